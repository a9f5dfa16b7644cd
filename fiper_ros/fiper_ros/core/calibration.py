"""Calibration: everything FIPER fits from successful ID rollouts (Sec. 4, App. A).

:func:`calibrate` trains RND-OE on the embeddings of the successful calibration rollouts (App. A.2;
like the paper, the same rollouts also calibrate the thresholds, Remark 1), fixes the ACE ranges
``R_d`` (App. A.1), scores every calibration step, aggregates the scores (eqs. 2, 5) and fits the
thresholds ``gamma_O,t`` and ``gamma_A,t`` (Sec. 4.3, App. A.3).

A calibration directory holds ``calibration.yaml`` and the RND-OE files (``rnd_oe.pt`` and
``rnd_oe.json``). The YAML carries a content hash over its own content and the network weights, and
``rnd_oe.json`` must describe the network the YAML names, so a modified, incomplete or mismatched
directory is refused on load with one line naming the file (:func:`load_calibration`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fiper_ros.core.ace import action_ranges, cell_size
from fiper_ros.core.compat import Profile, get_profile
from fiper_ros.core.fusion import COMBINES
from fiper_ros.core.kinematics import ActionProjection, ForwardKinematics
from fiper_ros.core.rnd_oe import CONFIG_FILE as RND_CONFIG_FILE
from fiper_ros.core.rnd_oe import RNDOE, ProgressCallback, RNDConfig, RNDError
from fiper_ros.core.rnd_oe import WEIGHTS_FILE as RND_WEIGHTS_FILE
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.scores import act_scores, obs_scores, rollout_positions
from fiper_ros.core.thresholds import Threshold, ThresholdSettings, fit_threshold
from fiper_ros.core.window import MODES, aggregate

LOG = logging.getLogger(__name__)

FORMAT_VERSION = 1
CALIBRATION_FILE = "calibration.yaml"


class CalibrationError(ValueError):
    """A calibration cannot be fitted, read or used."""


class CalibrationMismatch(CalibrationError):
    """Live data does not match the calibration (e.g. another policy, robot or task)."""

    def __init__(self, field_name: str, expected: Any, got: Any) -> None:
        super().__init__(f"calibration mismatch for {field_name}: expected {expected}, got {got}")
        self.field = field_name
        self.expected = expected
        self.got = got


@dataclass(frozen=True)
class CalibrationSettings:
    """Hyperparameters of one calibration.

    Attributes:
        alpha: ACE cell size factor; ``None`` uses the profile's default (0.03).
        window_obs: ``w_O`` of eq. (2), in policy steps.
        window_act: ``w_A`` of eq. (5).
        aggregation: ``"window"``, ``"cumulative"`` or ``"single"``.
        threshold: Threshold kind, see :mod:`fiper_ros.core.thresholds`.
        delta: Target false-alarm rate.
        combine: ``"and"`` (eq. 7) or ``"or"``.
        rnd: RND-OE network and training configuration.
        seed: Seed of RND-OE and of the CP band split.
        profile: ``"paper"`` or ``"reference"`` (see :mod:`fiper_ros.core.compat`).
        extension: Threshold extension rule; ``None`` uses the profile's.
        min_support: Support rule of per-step statistics; ``None`` uses the profile's.
        band_split: Fraction of rollouts in ``I1`` of the CP band.
        min_rollouts: Fewest successful calibration rollouts accepted.
        action_dims: ``(start, stop)`` of the action channels used by ACE (see
            :class:`fiper_ros.core.kinematics.ActionProjection`); ``None``: its default.
        control_dt: Seconds per action, for ``joint_velocity`` actions.
    """

    alpha: float | None = None
    window_obs: int = 5
    window_act: int = 5
    aggregation: str = "window"
    threshold: str = "cp_band"
    delta: float = 0.05
    combine: str = "and"
    rnd: RNDConfig = field(default_factory=RNDConfig.small)
    seed: int = 0
    profile: str = "paper"
    extension: str | None = None
    min_support: int | None = None
    band_split: float = 0.5
    min_rollouts: int = 4
    action_dims: tuple[int, int] | None = None
    control_dt: float | None = None

    def __post_init__(self) -> None:
        get_profile(self.profile)
        if self.aggregation not in MODES:
            raise CalibrationError(f"unknown aggregation {self.aggregation!r}; expected one of {MODES}")
        if self.combine not in COMBINES:
            raise CalibrationError(f"unknown combine {self.combine!r}; expected one of {COMBINES}")
        if min(self.window_obs, self.window_act) < 1:
            raise CalibrationError("window sizes must be >= 1")
        if self.min_rollouts < 2:
            raise CalibrationError(f"min_rollouts must be >= 2, got {self.min_rollouts}")

    @property
    def resolved_alpha(self) -> float:
        """``alpha`` or the profile's default."""
        return self.profile_obj.alpha if self.alpha is None else self.alpha

    @property
    def profile_obj(self) -> Profile:
        """The :class:`Profile` named by ``profile``."""
        return get_profile(self.profile)

    def threshold_settings(self) -> ThresholdSettings:
        """Threshold fitting settings implied by these settings and the profile."""
        profile = self.profile_obj
        return ThresholdSettings(
            kind=self.threshold,
            delta=self.delta,
            extension=profile.extension if self.extension is None else self.extension,
            min_support=profile.min_support if self.min_support is None else self.min_support,
            band_split=self.band_split,
            band_sign=profile.band_sign,
            conformal=profile.conformal,
            seed=self.seed,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form for YAML."""
        data = asdict(self)
        data["rnd"] = self.rnd.to_dict()
        data["action_dims"] = None if self.action_dims is None else list(self.action_dims)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CalibrationSettings:
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        data["rnd"] = RNDConfig.from_dict(data["rnd"])
        if data.get("action_dims") is not None:
            data["action_dims"] = tuple(data["action_dims"])
        return cls(**data)


@dataclass
class Calibration:
    """A fitted FIPER calibration; ``task`` is that of its rollouts ("" if they did not say)."""

    settings: CalibrationSettings
    rnd: RNDOE
    ranges: np.ndarray
    threshold_obs: Threshold
    threshold_act: Threshold
    embedding_dim: int
    action_dim: int
    horizon: int
    exec_steps: int
    action_space: str
    num_rollouts: int
    task: str = ""

    @property
    def profile(self) -> Profile:
        """The method profile."""
        return self.settings.profile_obj

    @property
    def cell(self) -> np.ndarray:
        """ACE cell size ``alpha * R_d``."""
        return cell_size(self.ranges, self.settings.resolved_alpha)

    def projection(self, fk: ForwardKinematics | None = None) -> ActionProjection:
        """The action-to-position mapping ACE uses (``fk`` is needed for joint-space actions)."""
        return ActionProjection(self.action_space, self.settings.action_dims, fk, self.settings.control_dt)

    def check_compatible(
        self,
        embedding_dim: int | None = None,
        action_dim: int | None = None,
        horizon: int | None = None,
        *,
        exec_steps: int | None = None,
        action_space: str | None = None,
        task: str | None = None,
    ) -> None:
        """Raise :class:`CalibrationMismatch` naming the first field that differs (``None``: not checked;
        a task is compared only when both this calibration and the caller know it)."""
        for name, got in (("embedding_dim", embedding_dim), ("action_dim", action_dim), ("horizon", horizon),
                          ("exec_steps", exec_steps)):
            expected = getattr(self, name)
            if got is not None and int(got) != expected:
                raise CalibrationMismatch(name, expected, int(got))
        if action_space is not None and action_space != self.action_space:
            raise CalibrationMismatch("action_space", self.action_space, action_space)
        if task and self.task and task != self.task:
            raise CalibrationMismatch("task", self.task, task)

    def _content(self) -> dict[str, Any]:
        return {
            "format_version": FORMAT_VERSION,
            "settings": self.settings.to_dict(),
            "profile": self.settings.profile,
            "delta": float(self.settings.delta),
            "windows": {"obs": self.settings.window_obs, "act": self.settings.window_act},
            "aggregation": self.settings.aggregation,
            "threshold_kind": self.settings.threshold,
            "alpha": float(self.settings.resolved_alpha),
            "ranges": [float(r) for r in self.ranges],
            "thresholds": {"obs": self.threshold_obs.to_dict(), "act": self.threshold_act.to_dict()},
            "embedding_dim": self.embedding_dim,
            "action_dim": self.action_dim,
            "horizon": self.horizon,
            "exec_steps": self.exec_steps,
            "action_space": self.action_space,
            "num_rollouts": self.num_rollouts,
            # Only when known: calibrations written before the task was recorded keep their content hash.
            **({"task": self.task} if self.task else {}),
        }

    @property
    def content_hash(self) -> str:
        """SHA-256 over the YAML content (without the hash) and the RND-OE weights."""
        return _content_hash(self._content(), self.rnd)

    def save(self, directory: str | Path) -> Path:
        """Write ``calibration.yaml`` and the RND-OE files into ``directory``; returns the YAML path."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self.rnd.save(directory)
        content = self._content()
        content["content_hash"] = _content_hash(content, self.rnd)
        path = directory / CALIBRATION_FILE
        path.write_text(yaml.safe_dump(content, sort_keys=False))
        return path


def _content_hash(content: dict[str, Any], rnd: RNDOE) -> str:
    digest = hashlib.sha256(yaml.safe_dump(content, sort_keys=True).encode())
    digest.update(rnd.digest().encode())
    return digest.hexdigest()


def _one_line(error: object) -> str:
    """``error`` as one line (YAML and torch errors span several)."""
    return " ".join(str(error).split())


def _read_yaml(path: Path) -> dict[str, Any]:
    """``calibration.yaml`` as a mapping of the supported format version."""
    try:
        with path.open() as stream:
            content = yaml.safe_load(stream)
    except OSError as error:
        raise CalibrationError(f"{path}: unreadable ({_one_line(error)})") from error
    except yaml.YAMLError as error:
        raise CalibrationError(f"{path}: not valid YAML ({_one_line(error)})") from error
    if not isinstance(content, dict):
        got = "an empty file" if content is None else f"a YAML {type(content).__name__}"
        raise CalibrationError(f"{path}: not a calibration (a YAML mapping expected, got {got})")
    if content.get("format_version") != FORMAT_VERSION:
        raise CalibrationError(f"{path}: format_version {content.get('format_version')!r} not supported "
                               f"(this code reads {FORMAT_VERSION})")
    return content


def _check_description(directory: Path, embedding_dim: int, settings: CalibrationSettings) -> None:
    """``rnd_oe.json`` must describe the network ``calibration.yaml`` names (``RNDOE.save``'s fields):
    the content hash covers the YAML and the weights, this check the description."""
    path = directory / RND_CONFIG_FILE
    try:
        described = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise CalibrationError(f"{path}: unreadable ({_one_line(error)})") from error
    expected = {"embedding_dim": embedding_dim, "seed": settings.seed, "config": settings.rnd.to_dict()}
    if described != expected:
        raise CalibrationError(f"{path}: does not describe the RND-OE network of {CALIBRATION_FILE} (file modified, "
                               "or files of different runs)")


def _load_rnd(directory: Path) -> RNDOE:
    """The RND-OE model, once its description is known to be right: any failure is the weights'."""
    path = directory / RND_WEIGHTS_FILE
    try:
        return RNDOE.load(directory)
    except Exception as error:  # noqa: BLE001 - torch raises OSError, RuntimeError, pickle errors for a damaged file
        cause = error.__cause__ if isinstance(error, RNDError) and error.__cause__ is not None else error
        detail = re.split(r"(?<=\.)\s|\n", str(cause).strip(), maxsplit=1)[0]
        raise CalibrationError(f"{path}: not readable RND-OE weights (damaged, or not written by fiper calibrate: "
                               f"{type(cause).__name__}{': ' + detail if detail else ''})") from error


def load_calibration(directory: str | Path) -> Calibration:
    """Read a calibration directory written by :meth:`Calibration.save`.

    Raises :class:`CalibrationError` with one line naming the file for a missing directory or file, a
    file that does not parse, an unknown format version, a missing or malformed entry, a modified file
    (content hash, RND-OE description) and weights that do not load.
    """
    directory = Path(directory)
    path = directory / CALIBRATION_FILE
    if not directory.is_dir():
        raise CalibrationError(f"calibration directory not found: {directory}")
    for name in (CALIBRATION_FILE, RND_CONFIG_FILE, RND_WEIGHTS_FILE):
        if not (directory / name).is_file():
            raise CalibrationError(f"calibration file not found: {directory / name}")
    content = _read_yaml(path)
    try:
        settings = CalibrationSettings.from_dict(content["settings"])
        fields = {
            "ranges": np.asarray(content["ranges"], dtype=np.float64),
            "threshold_obs": Threshold.from_dict(content["thresholds"]["obs"]),
            "threshold_act": Threshold.from_dict(content["thresholds"]["act"]),
            "embedding_dim": int(content["embedding_dim"]),
            "action_dim": int(content["action_dim"]),
            "horizon": int(content["horizon"]),
            "exec_steps": int(content["exec_steps"]),
            "action_space": str(content["action_space"]),
            "num_rollouts": int(content["num_rollouts"]),
            "task": str(content.get("task", "")),
        }
    except KeyError as error:
        raise CalibrationError(f"{path}: missing entry {error}") from error
    except (TypeError, ValueError) as error:  # ThresholdError, RNDConfig and settings values
        raise CalibrationError(f"{path}: malformed entry ({_one_line(error)})") from error
    _check_description(directory, fields["embedding_dim"], settings)
    rnd = _load_rnd(directory)
    calibration = Calibration(settings=settings, rnd=rnd, **fields)
    stored = content.pop("content_hash", None)
    if stored != _content_hash(content, rnd) or stored != calibration.content_hash:
        raise CalibrationError(f"{path}: content hash mismatch (file or weights modified, or files of different runs)")
    return calibration


def _layout(rollout: Rollout) -> tuple[int, int, int, int, str]:
    """``(embedding_dim, action_dim, horizon, exec_steps, action_space)`` of a rollout."""
    shape = rollout.actions.shape
    return rollout.embeddings.shape[1], shape[3], shape[2], rollout.exec_steps, rollout.action_space


def _task_of(rollouts: Sequence[Rollout]) -> str:
    """The one task the rollouts name ("" if none does); rollouts of several tasks are refused."""
    tasks = sorted({r.task for r in rollouts if r.task})
    if len(tasks) > 1:
        raise CalibrationError(f"calibration rollouts of several tasks ({', '.join(tasks)}): calibrate each task "
                               "on its own")
    return tasks[0] if tasks else ""


def _check_consistent(rollouts: Sequence[Rollout]) -> tuple[int, int, int, int, str]:
    expected = _layout(rollouts[0])
    names = ("embedding_dim", "action_dim", "horizon", "exec_steps", "action_space")
    for rollout in rollouts[1:]:
        for name, want, have in zip(names, expected, _layout(rollout)):
            if want != have:
                raise CalibrationMismatch(f"{name} of rollout {rollout.rollout_id!r}", want, have)
    return expected


def calibrate(
    rollouts: Sequence[Rollout],
    settings: CalibrationSettings | None = None,
    fk: ForwardKinematics | None = None,
    progress: ProgressCallback | None = None,
) -> Calibration:
    """Fit RND-OE, ``R_d`` and both thresholds from calibration rollouts.

    Only rollouts with ``success is True`` are used, except that the ``"reference"`` profile takes
    ``R_d`` over all given rollouts as the authors' code does.

    Args:
        rollouts: Calibration rollouts.
        settings: Hyperparameters; defaults to :class:`CalibrationSettings`.
        fk: Forward kinematics for joint-space actions.
        progress: Called after every RND-OE training epoch.
    """
    settings = settings or CalibrationSettings()
    good = successful(list(rollouts))
    if len(good) < settings.min_rollouts:
        raise CalibrationError(
            f"calibration needs at least {settings.min_rollouts} successful rollouts, got {len(good)} "
            f"(of {len(rollouts)} given)"
        )
    embedding_dim, action_dim, horizon, exec_steps, action_space = _check_consistent(list(rollouts))
    task = _task_of(rollouts)
    profile = settings.profile_obj
    projection = ActionProjection(action_space, settings.action_dims, fk, settings.control_dt)
    # Positions are recomputed in the second pass instead of kept: a task with B = 256 holds hundreds
    # of MB of them (FK for joint-space actions is therefore evaluated twice, offline only).
    ranges = action_ranges(rollout_positions(r, projection) for r in (rollouts if profile.ranges_from_all else good))
    cell = cell_size(ranges, settings.resolved_alpha)
    LOG.info("calibrating on %d successful rollouts (R_d = %s)", len(good), np.array2string(ranges, precision=4))
    rnd = RNDOE.fit(np.concatenate([r.embeddings for r in good]), settings.rnd, settings.seed, progress)
    mode = settings.aggregation
    curves_obs = [aggregate(obs_scores(rnd, r.embeddings, profile), mode, settings.window_obs) for r in good]
    curves_act = [
        aggregate(act_scores(rollout_positions(r, projection), cell, profile), mode, settings.window_act) for r in good
    ]
    threshold_settings = settings.threshold_settings()
    return Calibration(
        settings=settings,
        rnd=rnd,
        ranges=ranges,
        threshold_obs=fit_threshold(curves_obs, threshold_settings),
        threshold_act=fit_threshold(curves_act, threshold_settings),
        embedding_dim=embedding_dim,
        action_dim=action_dim,
        horizon=horizon,
        exec_steps=exec_steps,
        action_space=action_space,
        num_rollouts=len(good),
        task=task,
    )
