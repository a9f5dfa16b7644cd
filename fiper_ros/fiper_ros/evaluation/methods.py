"""The evaluated methods and the per-step score streams they read (Table 1 of the paper, plus a floor).

A *stream* is one per-step score per rollout step (``s_RND``, ``s_ACE`` or a baseline's score). Every
method but FIPER thresholds one stream; FIPER fuses the RND-OE and ACE streams with AND/OR (eq. 7).
:class:`MethodSettings` holds every hyperparameter that changes a stream, so it is part of the
score-cache key.

The elapsed-time baseline is the floor every detector has to beat: its per-step score is 1,
so its cumulative sum at policy step ``t`` is ``t + 1``, the steps elapsed, and with the CP constant
threshold it alarms at step ``k`` of every rollout longer than ``k``, ``k`` the conformal quantile of
the calibration successes' lengths (calibrated as every other method, on the same conformal part). It
has this one configuration (:attr:`Method.fixed`): nothing is selected for it.

Observation-only data (rollouts without action batches) can be evaluated by the methods that
read observations alone (:func:`observation_methods`): the elapsed time, PCA-kmeans, logpZO and RND-OE.

A user's external scores (:mod:`fiper_ros.evaluation.external`) are a method too, named by their stream
``external_<name>`` (:func:`method_of`), swept like a built-in single-stream method.

A :class:`Combination` is a method too: named detectors (streams) voting under the thresholds of
:mod:`fiper_ros.evaluation.joint_sweep` (one conformal factor for ``max`` / ``kth:K``, one per detector for
``and`` / ``or``). :func:`default_combinations` names the ones every run evaluates.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from fiper_ros.baselines.rnd_a import RNDAConfig
from fiper_ros.core.calibration import SPLITS, CalibrationSettings
from fiper_ros.core.consistency import ConsistencySettings
from fiper_ros.core.detectors import (ACE, CONSISTENCY, EXTERNAL_PREFIX, PROGRESS, RND_OE, DetectorInfo, info,
                                      signal_stream)
from fiper_ros.core.equalisation import DEFAULT_LEVEL, check_equalisation
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.kinematics import RobotModel
from fiper_ros.core.logpzo import LogpZOConfig
from fiper_ros.core.pca_kmeans import PCAKMeansConfig
from fiper_ros.core.profiles import get_profile
from fiper_ros.core.progress import ProgressSettings
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.scorers import DetectorOptions
from fiper_ros.evaluation.errors import SettingsError
from fiper_ros.evaluation.external import ExternalScores


@dataclass(frozen=True)
class Method:
    """Display name and the streams a method reads."""

    label: str
    streams: tuple[str, ...]
    fixed: tuple[str, str] | None = None
    """``(window label, threshold kind)`` of a method with a single configuration; ``None``: swept."""
    needs_actions: bool = False
    """Whether its streams read the sampled action batches (not available in observation-only data)."""


ELAPSED = "elapsed"

#: Methods in the column order of Table 1, after the elapsed-time floor.
METHODS: dict[str, Method] = {
    ELAPSED: Method("Elapsed", (ELAPSED,), ("cum", "cp_constant")),
    "pca_kmeans": Method("PCA-kmeans", ("pca_kmeans",)),
    "logpzo": Method("logpZO", ("logpzo",)),
    "rnd_a": Method("RND-A", ("rnd_a",), needs_actions=True),
    "stac": Method("STAC", ("stac",), needs_actions=True),
    "rnd_oe": Method("RND-OE", ("rnd_oe",)),
    "ace": Method("ACE", ("ace",), needs_actions=True),
    "fiper": Method("FIPER", ("rnd_oe", "ace"), needs_actions=True),
    PROGRESS: Method("Progress", (PROGRESS,)),
    CONSISTENCY: Method("Consistency", (CONSISTENCY,), needs_actions=True),
}


def stream_info(name: str) -> DetectorInfo:
    """The core's :func:`~fiper_ros.core.detectors.info` of a stream an evaluation is asked for; a name that is no
    stream is a :class:`SettingsError` naming the known ones."""
    try:
        return info(name)
    except ChoiceError as error:
        raise SettingsError(str(error)) from None


def method_of(name: str) -> Method:
    """The method ``name``: a built-in one (:data:`METHODS`) or a user's external scores (``external_<name>``, one
    stream); :class:`SettingsError` naming the methods otherwise."""
    if name in METHODS:
        return METHODS[name]
    if name.startswith(EXTERNAL_PREFIX):
        return Method(stream_info(name).label, (name,))
    raise SettingsError(f"unknown method {name!r}; expected some of {list(METHODS)} or external_<name>")


def fitted(stream: str) -> bool:
    """Whether ``stream`` learns from the calibration successes (STAC, a logged signal, external scores and the
    elapsed time do not: their scores depend neither on the calibration split nor on the seed)."""
    return info(stream).fitted


#: Streams fitted without randomness (ACE's ``R_d``): they depend on the seed only through the split.
DETERMINISTIC_FITS = frozenset({"ace"})

#: Evaluation default for RND-OE: the core's small network with a CPU training budget
#: (lr 1e-3, at most 50 epochs, early stopping as in the paper).
EVAL_RND = RNDConfig(max_epochs=50, lr=1e-3)


@dataclass(frozen=True)
class MethodSettings:
    """Hyperparameters of every stream.

    Attributes:
        profile: ``"paper"`` or ``"reference"`` (:mod:`fiper_ros.core.profiles`): ACE/RND-OE score
            details, threshold details and the DT normalisation.
        alpha: ACE cell size factor; ``None`` uses the profile's.
        rnd: RND-OE network and training.
        pca_kmeans, logpzo, rnd_a: The baselines' configurations.
        progress, consistency: The progress and action-consistency detectors' settings.
        robot: FK and control period for ACE on joint-space actions (App. A.1); ``None`` for
            end-effector actions.
        split: Which calibration successes fit the score models and which the thresholds' conformal
            quantiles (:data:`fiper_ros.core.calibration.SPLITS`; ``"split"``, split conformal, by default).
        shape_folds: With ``"split"``: 0 takes the thresholds' per-step shape from the fit part's in-sample curves,
            K >= 2 from cross-fitted ones (:class:`fiper_ros.core.calibration.CalibrationSettings`).
        external: A user's external scores, each the stream ``external_<name>`` (keyed in the cache by the file's
            content hash).
    """

    profile: str = "paper"
    alpha: float | None = None
    rnd: RNDConfig = EVAL_RND
    pca_kmeans: PCAKMeansConfig = field(default_factory=PCAKMeansConfig)
    logpzo: LogpZOConfig = field(default_factory=LogpZOConfig)
    rnd_a: RNDAConfig = field(default_factory=RNDAConfig)
    progress: ProgressSettings = field(default_factory=ProgressSettings)
    consistency: ConsistencySettings = field(default_factory=ConsistencySettings)
    robot: RobotModel | None = None
    split: str = "split"
    shape_folds: int = 0
    external: tuple[ExternalScores, ...] = ()

    def __post_init__(self) -> None:
        try:
            get_profile(self.profile)
        except ChoiceError as error:
            raise SettingsError(str(error)) from None
        if self.split not in SPLITS:
            raise SettingsError(f"unknown split {self.split!r}; expected one of {SPLITS}")
        self.calibration_settings(0)  # shape_folds: refused now, in the core's words

    def detector_options(self, robot: RobotModel | None = None) -> DetectorOptions:
        """Every core detector's own settings, as a calibration of this profile passes them to its scorers (the
        control period of ``robot`` for ACE on joint velocities)."""
        alpha = get_profile(self.profile).alpha if self.alpha is None else self.alpha
        return DetectorOptions(self.rnd, alpha, None, None if robot is None else robot.control_dt, self.progress,
                               self.consistency, self.logpzo, self.pca_kmeans)

    def calibration_settings(self, seed: int) -> CalibrationSettings:
        """The core calibration settings of ``seed``: profile, split (with its shape folds) and the seed of the
        split and CP band."""
        return CalibrationSettings(profile=self.profile, seed=seed, split=self.split, shape_folds=self.shape_folds)

    def split_settings(self) -> dict[str, Any]:
        """The split and its own settings, as the core writes them (part of a fitted stream's cache key)."""
        data = self.calibration_settings(0).to_dict()
        return ({key: data[key] for key in ("split", "conformal_fraction", "folds", "shape_folds") if key in data}
                or {"split": "same"})

    def external_scores(self, stream: str) -> ExternalScores:
        """The external scores of the stream ``external_<name>``; ``ValueError`` if none were given."""
        for external in self.external:
            if external.stream == stream:
                return external
        raise ValueError(f"no external scores for the stream {stream!r}")

    def stream_seed(self, stream: str, seed: int) -> int | None:
        """The seed ``stream``'s scores depend on (``None``: none): through training and through the split."""
        if not fitted(stream) or (stream in DETERMINISTIC_FITS and self.split == "same"):
            return None
        return seed

    @classmethod
    def tiny(cls, profile: str = "paper") -> MethodSettings:
        """Very small networks and budgets, for tests and smoke runs (numbers are not meaningful)."""
        tiny_rnd = RNDConfig(trunk=(32, 32), head=(32,), out_dim=16, max_epochs=8, lr=1e-3)
        return cls(
            profile=profile,
            rnd=tiny_rnd,
            pca_kmeans=PCAKMeansConfig(components=8, clusters=16),
            logpzo=LogpZOConfig(hidden=(32, 32), epochs=8),
            rnd_a=RNDAConfig(channels=8, train_samples=2, score_samples=8, rnd=tiny_rnd),
        )

    def stream_settings(self, stream: str, joint_space: bool = False) -> dict[str, Any]:
        """The settings that determine ``stream`` (plain data, for the cache key); the robot model
        only for ACE on a task with ``joint_space`` actions, the split for every fitted stream."""
        common: dict[str, Any] = {"profile": self.profile}
        if stream == ELAPSED:
            return {}
        if fitted(stream):
            common.update(self.split_settings())
        if stream == "rnd_oe":
            return {**common, "rnd": self.rnd.to_dict()}
        if stream == "ace":
            robot = {"robot": self.robot.to_dict()} if joint_space and self.robot is not None else {}
            return {**common, "alpha": self.alpha, **robot}
        if stream == "stac":
            return common
        if stream == "pca_kmeans":
            return {**common, **asdict(self.pca_kmeans)}
        if stream == "logpzo":
            return {**common, **self.logpzo.to_dict()}
        if stream == "rnd_a":
            return {**common, **self.rnd_a.to_dict()}
        if stream == PROGRESS:
            return {**common, **asdict(self.progress)}
        if stream == CONSISTENCY:
            return {**common, **self.consistency.to_dict()}
        if info(stream).reads == "signal":
            return common  # the magnitude of the logged value: nothing to set
        if info(stream).reads == "external":
            return {"sha256": self.external_scores(stream).sha256}  # taken as they are: the file alone
        raise ValueError(f"unknown stream {stream!r}")


@dataclass(frozen=True)
class Combination:
    """A named set of detectors (score streams), combined; its name is the method's in the tables."""

    name: str
    detectors: tuple[str, ...]
    label: str = ""
    """Its name for people (default: the name)."""
    equalise: str = "none"
    """How its joint combines equalise the detectors' tails (:mod:`fiper_ros.core.equalisation`; not ``"none"``:
    swept with the joint combines only)."""
    level: float = DEFAULT_LEVEL
    """The quantile level of ``equalise="quantile"``."""

    def __post_init__(self) -> None:
        if not self.detectors or len(set(self.detectors)) != len(self.detectors):
            raise SettingsError(f"combination {self.name!r}: distinct detectors needed, got {self.detectors}")
        for detector in self.detectors:
            stream_info(detector)
        check_equalisation(self.equalise, self.level)

    def equalised(self, equalise: str, level: float = DEFAULT_LEVEL) -> Combination:
        """The same detectors with their tails equalised by ``equalise``, named ``<name>_<equalise>``."""
        return Combination(f"{self.name}_{equalise}", self.detectors, f"{self.label or self.name} ({equalise})",
                           equalise, level)

    def method(self) -> Method:
        """The combination as a table column."""
        return Method(self.label or self.name, self.detectors,
                      needs_actions=any(info(d).reads == "actions" for d in self.detectors))


def parse_combination(text: str) -> Combination:
    """``NAME=a+b+c`` (streams) as a :class:`Combination`; :class:`SettingsError` in one line otherwise."""
    name, _, members = text.partition("=")
    if not name or not members:
        raise SettingsError(f"combination {text!r}: expected NAME=DETECTOR+DETECTOR+... (e.g. obs=rnd_oe+logpzo+elapsed)")
    if name.strip() in METHODS:
        raise SettingsError(f"combination {text!r}: {name.strip()!r} is the name of a built-in method")
    return Combination(name.strip(), tuple(m.strip() for m in members.split("+") if m.strip()))


def pooled_methods(methods: tuple[str, ...]) -> tuple[Combination, ...]:
    """``methods`` as combinations, for thresholds pooled over tasks: each single method its stream alone, FIPER
    its pair (it votes with AND / OR), the elapsed time its cumulative count."""
    return tuple(Combination(m, method_of(m).streams, method_of(m).label) for m in methods)


def signal_methods(signals: tuple[str, ...]) -> tuple[Combination, ...]:
    """A logged per-step signal ``name`` as a method of its own (the stream ``signal_<name>``); a name that cannot
    be a stream is a :class:`SettingsError`."""
    try:
        streams = [signal_stream(name) for name in signals]
    except ChoiceError as error:
        raise SettingsError(str(error)) from None
    return tuple(Combination(stream, (stream,), f"signal {name}") for stream, name in zip(streams, signals))


def default_combinations(methods: tuple[str, ...], extra_streams: tuple[str, ...] = ()) -> tuple[Combination, ...]:
    """The combinations evaluated beside ``methods``: FIPER's pair under one threshold (``fiper_joint``) when
    FIPER is evaluated, and every stream of the evaluated methods (and ``extra_streams``, e.g. logged signals)
    together (``combined``)."""
    out = []
    if "fiper" in methods:
        out.append(Combination("fiper_joint", (RND_OE, ACE), "FIPER (joint)"))
    members = tuple(dict.fromkeys([*streams_of([m for m in methods if m != "fiper"]), *extra_streams]))
    if len(members) > 1:
        out.append(Combination("combined", members, "Combined"))
    return tuple(out)


def observation_methods(methods: tuple[str, ...]) -> tuple[str, ...]:
    """The methods of ``methods`` that need no action batches, in their order."""
    return tuple(m for m in methods if not method_of(m).needs_actions)


def streams_of(methods: list[str]) -> list[str]:
    """The distinct streams the methods read, in first-use order."""
    out: list[str] = []
    for name in methods:
        out.extend(s for s in method_of(name).streams if s not in out)
    return out
