"""What a calibration is fitted with: the detectors, their windows and options, the threshold, the combine and the
split (:class:`CalibrationSettings`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from fiper_ros.core.ace import check_alpha
from fiper_ros.core.calibration_file import CalibrationError
from fiper_ros.core.combination import SHAPE_KINDS, equalisable
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.consistency import ConsistencySettings
from fiper_ros.core.detectors import (ACE, CONSISTENCY, DETECTORS, LOGPZO, PCA_KMEANS, PROGRESS, RND_OE, check_declared,
                                      check_once, in_fusion_order, info)
from fiper_ros.core.equalisation import DEFAULT_LEVEL, check_equalisation
from fiper_ros.core.errors import CoreError
from fiper_ros.core.fusion import Combine
from fiper_ros.core.logpzo import LogpZOConfig
from fiper_ros.core.pca_kmeans import PCAKMeansConfig
from fiper_ros.core.profiles import Profile, get_profile
from fiper_ros.core.progress import ProgressSettings
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.scorers import DetectorOptions
from fiper_ros.core.thresholds import ThresholdSettings
from fiper_ros.core.window import MODES

#: Which successes fit the score models and which the thresholds (:mod:`fiper_ros.core.calibration.fit`).
SPLITS = ("split", "cross", "same")
#: Each option's detector: the option is written (and used) only when that detector is declared.
OPTION_OWNERS = {"rnd": RND_OE, "alpha": ACE, "action_dims": ACE, "control_dt": ACE, "progress": PROGRESS,
                 "consistency": CONSISTENCY, "logpzo": LOGPZO, "pca_kmeans": PCA_KMEANS}
#: Options that are dataclasses with their own plain-data form.
_NESTED = {"rnd": RNDConfig, "progress": ProgressSettings, "consistency": ConsistencySettings,
           "logpzo": LogpZOConfig, "pca_kmeans": PCAKMeansConfig}


def _ordered(detectors: tuple[str, ...]) -> tuple[str, ...]:
    """The declared detectors, each once, in the fusion's order (:func:`~fiper_ros.core.detectors.in_fusion_order`)."""
    for name in detectors:
        check_declared(name)
    return in_fusion_order(check_once(detectors))


@dataclass(frozen=True)
class CalibrationSettings:
    """Hyperparameters of one calibration.

    Attributes:
        detectors: The detectors calibrated and combined (:data:`fiper_ros.core.detectors.CALIBRATED` and logged
            signals ``signal_<name>``): FIPER's pair by default, ``("rnd_oe",)`` observation-only.
        window: Every detector's window in policy steps (``w`` of eqs. 2 and 5), unless ``windows`` names it.
        windows: Per-detector windows (``{"rnd_oe": 8, "ace": 50}``: ``w_O`` and ``w_A``).
        aggregation: ``"window"``, ``"max"`` (max-pooled window), ``"cumulative"`` or ``"single"``; a detector
            whose aggregation is fixed (the elapsed time) keeps its own.
        threshold: Threshold kind (:mod:`fiper_ros.core.thresholds`); a joint combine needs a kind with a shape.
        delta: Target false-alarm rate.
        combine: ``"and"`` (eq. 7), ``"or"``, ``"max"`` or ``"kth:K"`` (:class:`fiper_ros.core.fusion.Combine`).
        rnd: RND-OE network and training configuration.
        alpha: ACE cell size factor; ``None`` uses the profile's default (0.03).
        action_dims: ``(start, stop)`` of the action channels ACE uses
            (:class:`fiper_ros.core.kinematics.ActionProjection`); ``None``: its default.
        control_dt: Seconds per action, for ACE on ``joint_velocity`` actions.
        progress, consistency, logpzo, pca_kmeans: Those detectors' settings.
        seed: Seed of every fitted model and of the splits.
        profile: ``"paper"`` or ``"reference"`` (:mod:`fiper_ros.core.profiles`).
        extension: Threshold extension rule; ``None`` uses the profile's.
        min_support: Support rule of per-step statistics; ``None`` uses the profile's.
        band_split: Fraction of rollouts in ``I1`` of the CP band when the split gives no shape curves.
        min_rollouts: Fewest successful calibration rollouts accepted (per task).
        split: ``"split"`` (split conformal, default), ``"cross"`` (K-fold) or ``"same"`` (the paper's same-data
            calibration, not covered by Proposition 1).
        conformal_fraction: With ``"split"``: the fraction of the successes in the conformal set.
        folds: With ``"cross"``: the number of folds K.
        shape_folds: With ``"split"``: 0 fits the thresholds' per-step shape on the fit part's in-sample curves,
            K >= 2 on cross-fitted ones (each of K folds of the fit part scored by models fitted on the others).
        pooled: With rollouts of several tasks: one conformal factor over every task's conformal rollouts (each task
            normalised by its own shapes: kinds with a shape only), else per-task thresholds.
        equalise: With a joint combine: ``"none"`` (each detector's shape only), ``"quantile"`` or ``"tail"``: each
            detector's normalised score mapped by an equaliser fitted on the fit part's out-of-fold maxima
            (:mod:`fiper_ros.core.equalisation`).
        equalise_level: With ``"quantile"``: the quantile of the maxima mapped to 1 (otherwise the default).
    """

    detectors: tuple[str, ...] = DETECTORS
    window: int = 5
    windows: Mapping[str, int] = field(default_factory=dict)
    aggregation: str = "window"
    threshold: str = "cp_band"
    delta: float = 0.05
    combine: str = CombineMode.AND.value
    rnd: RNDConfig = field(default_factory=RNDConfig.small)
    alpha: float | None = None
    action_dims: tuple[int, int] | None = None
    control_dt: float | None = None
    progress: ProgressSettings = field(default_factory=ProgressSettings)
    consistency: ConsistencySettings = field(default_factory=ConsistencySettings)
    logpzo: LogpZOConfig = field(default_factory=LogpZOConfig)
    pca_kmeans: PCAKMeansConfig = field(default_factory=PCAKMeansConfig)
    seed: int = 0
    profile: str = "paper"
    extension: str | None = None
    min_support: int | None = None
    band_split: float = 0.5
    min_rollouts: int = 4
    split: str = "split"
    conformal_fraction: float = 0.5
    folds: int = 5
    shape_folds: int = 0
    pooled: bool = False
    equalise: str = "none"
    equalise_level: float = DEFAULT_LEVEL

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "detectors", _ordered(tuple(self.detectors)))
            self._canonical_windows()
            check_equalisation(self.equalise, self.equalise_level)
            if self.equalise != "quantile":  # one form per meaning: the level serves the quantile map only
                object.__setattr__(self, "equalise_level", DEFAULT_LEVEL)
            self._check()
        except CalibrationError:
            raise
        except (CoreError, ValueError, TypeError) as error:
            raise CalibrationError(str(error)) from error

    def _canonical_windows(self) -> None:
        """One form per meaning (so equal settings hash equally): every declared detector's own equal window is
        ``window``, and ``windows`` keeps only the windows that differ from it (a window of a detector that is not
        declared stays, for :meth:`_check` to refuse)."""
        windows = {str(k): int(v) for k, v in dict(self.windows).items()}
        if set(windows) == set(self.detectors) and len(set(windows.values())) == 1:
            object.__setattr__(self, "window", next(iter(windows.values())))
        object.__setattr__(self, "windows", {k: v for k, v in sorted(windows.items()) if v != self.window})

    def _check(self) -> None:
        if self.split not in SPLITS:
            raise CalibrationError(f"unknown split {self.split!r}; expected one of {SPLITS}")
        if not 0.0 < self.conformal_fraction < 1.0:
            raise CalibrationError(f"conformal_fraction must be in (0, 1), got {self.conformal_fraction}")
        if self.folds < 2:
            raise CalibrationError(f"folds must be >= 2, got {self.folds}")
        if self.shape_folds == 1 or self.shape_folds < 0:
            raise CalibrationError(f"shape_folds must be 0 (in-sample shapes) or >= 2, got {self.shape_folds}")
        if self.shape_folds and self.split != "split":
            raise CalibrationError(f"shape_folds applies to the split conformal calibration (split 'split'), not to "
                                   f"{self.split!r}")
        get_profile(self.profile)
        if self.aggregation not in MODES:
            raise CalibrationError(f"unknown aggregation {self.aggregation!r}; expected one of {MODES}")
        combine = Combine.parse(self.combine)
        combine.votes(len(self.detectors))  # kth:K needs K detectors
        if self.normalised and self.threshold not in SHAPE_KINDS:
            why = "a joint combine" if combine.joint else "pooled thresholds"
            raise CalibrationError(f"{why} normalises each detector by its shape: threshold one of {', '.join(SHAPE_KINDS)}, "
                                   f"not {self.threshold}")
        if self.equalise != "none" and not combine.joint:
            raise CalibrationError(f"equalise {self.equalise} applies to a joint combine (max, kth:K), not "
                                   f"{self.combine}")
        if not equalisable(self.equalise, self.threshold):
            raise CalibrationError(f"equalise {self.equalise} divides by a positive quantile of the fit part's maxima, "
                                   f"which the {self.threshold} shape centres on 0: equalise tail instead")
        unknown = sorted(set(self.windows) - set(self.detectors))
        if unknown:
            raise CalibrationError(f"windows of undeclared detectors: {', '.join(unknown)} (detectors "
                                   f"{','.join(self.detectors)})")
        if min([self.window, *self.windows.values()]) < 1:
            raise CalibrationError("window sizes must be >= 1")
        if self.min_rollouts < 2:
            raise CalibrationError(f"min_rollouts must be >= 2, got {self.min_rollouts}")
        if self.seed < 0:
            raise CalibrationError(f"seed must be >= 0, got {self.seed}")
        if self.alpha is not None:
            check_alpha(self.alpha)
        self.threshold_settings()  # delta, band_split, ...: refused now, not after a model's training

    @property
    def has_ace(self) -> bool:
        """Whether ACE is among the declared detectors."""
        return ACE in self.detectors

    @property
    def needs_actions(self) -> bool:
        """Whether a declared detector reads the action batches (ACE, action consistency)."""
        return any(info(d).reads == "actions" for d in self.detectors)

    @property
    def combine_rule(self) -> Combine:
        """:attr:`combine` parsed."""
        return Combine.parse(self.combine)

    @property
    def normalised(self) -> bool:
        """Whether every detector is normalised by its shape (a joint combine or thresholds pooled over tasks), its
        curves split into shape and conformal halves where the split has no fit part."""
        return self.combine_rule.joint or self.pooled

    @property
    def votes(self) -> int:
        """How many declared detectors must exceed their thresholds at a step for an alarm."""
        return self.combine_rule.votes(len(self.detectors))

    def window_of(self, detector: str) -> int:
        """``w`` of ``detector``."""
        return self.windows.get(detector, self.window)

    def aggregation_of(self, detector: str) -> str:
        """The aggregation of ``detector``: its fixed one (the elapsed time: cumulative) or :attr:`aggregation`."""
        return info(detector).aggregation or self.aggregation

    def shape_of(self, detector: str) -> str:
        """The normalisation of ``detector`` in a joint combination: its fixed one or :attr:`threshold`."""
        return info(detector).shape or self.threshold

    @property
    def resolved_alpha(self) -> float:
        """``alpha`` or the profile's default."""
        return self.profile_obj.alpha if self.alpha is None else self.alpha

    @property
    def profile_obj(self) -> Profile:
        """The :class:`Profile` named by ``profile``."""
        return get_profile(self.profile)

    def options(self) -> DetectorOptions:
        """Every detector's own settings, as the scorers take them."""
        return DetectorOptions(self.rnd, self.resolved_alpha, self.action_dims, self.control_dt, self.progress,
                               self.consistency, self.logpzo, self.pca_kmeans)

    def threshold_settings(self, kind: str | None = None) -> ThresholdSettings:
        """Threshold fitting settings implied by these settings and the profile (``kind``: another kind)."""
        profile = self.profile_obj
        return ThresholdSettings(
            kind=kind or self.threshold,
            delta=self.delta,
            extension=profile.extension if self.extension is None else self.extension,
            min_support=profile.min_support if self.min_support is None else self.min_support,
            band_split=self.band_split,
            band_sign=profile.band_sign,
            conformal=profile.conformal,
            seed=self.seed,
            band_rule=profile.band_rule,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form for YAML: a detector's options only when it is declared, the split's own settings only
        where they apply, ``windows``, ``pooled`` and the equalisation only when set."""
        data = asdict(self)
        for name, kind in _NESTED.items():
            value = getattr(self, name)
            data[name] = value.to_dict() if hasattr(value, "to_dict") else asdict(value)
        data["action_dims"] = None if self.action_dims is None else list(self.action_dims)
        data["detectors"] = list(self.detectors)
        data["windows"] = dict(self.windows)
        unused = {"split": ("folds",), "cross": ("conformal_fraction", "shape_folds"),
                  "same": ("conformal_fraction", "folds", "shape_folds")}[self.split]
        unused += tuple(option for option, owner in OPTION_OWNERS.items() if owner not in self.detectors)
        unused += ("windows",) if not self.windows else ()
        unused += ("pooled",) if not self.pooled else ()
        unused += ("shape_folds",) if not self.shape_folds else ()
        unused += ("equalise",) if self.equalise == "none" else ()
        unused += ("equalise_level",) if self.equalise != "quantile" else ()
        return {k: v for k, v in data.items() if k not in unused}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CalibrationSettings:
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        for name, kind in _NESTED.items():
            if name in data:
                value = data[name]
                data[name] = kind.from_dict(value) if hasattr(kind, "from_dict") else kind(**value)
        if data.get("action_dims") is not None:
            data["action_dims"] = tuple(data["action_dims"])
        data["detectors"] = tuple(data.get("detectors", DETECTORS))
        return cls(**data)

    @classmethod
    def from_v2(cls, data: Mapping[str, Any]) -> CalibrationSettings:
        """The settings of a calibration of format 2 (``window_obs`` / ``window_act``; no ``split``: same data; no
        ``detectors``: FIPER's pair)."""
        data = dict(data)
        data.setdefault("split", "same")
        detectors = tuple(data.pop("detectors", DETECTORS))
        window_obs, window_act = data.pop("window_obs", 5), data.pop("window_act", None)
        windows = {ACE: window_act} if ACE in detectors and window_act not in (None, window_obs) else {}
        return cls.from_dict({**data, "detectors": detectors, "window": window_obs, "windows": windows})
