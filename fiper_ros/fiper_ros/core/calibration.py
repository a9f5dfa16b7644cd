"""Calibration: everything FIPER fits from successful ID rollouts (Sec. 4, App. A).

:func:`calibrate` fixes the ACE ranges ``R_d`` (App. A.1), trains RND-OE on embeddings (App. A.2), scores
the calibration steps, aggregates the scores (eqs. 2, 5) and fits the thresholds ``gamma_O,t`` and
``gamma_A,t`` (Sec. 4.3, App. A.3). Which successes serve which part is the ``split``:

- ``"split"`` (default): split conformal. A seeded ``conformal_fraction`` of the successes is the
  conformal set: nothing is fitted on it but the thresholds' conformal quantiles. RND-OE, ``R_d`` and the
  thresholds' per-step shape (the CP band's ``mu``, ``s``) are fitted on the rest. A new successful
  rollout is then exchangeable with the conformal set, as Proposition 1 assumes (Remark 1: ``D_ID`` and
  ``D_c`` disjoint), and a guaranteed threshold kind (``GUARANTEED_KINDS``) alarms on at most a fraction
  delta of new successes.
- ``"cross"``: K-fold cross-fitting. Each success is scored by RND-OE and ``R_d`` fitted without its fold,
  the thresholds are fitted on all these out-of-fold curves (the CP band split inside them), and the
  deployed RND-OE and ``R_d`` are fitted on all successes. Every rollout serves both purposes; the
  deployed model saw all of them, so the guarantee is approximate (it holds to the extent that a model
  fitted on all M successes scores a new one like a fold model scores its held-out fold), not
  finite-sample.
- ``"same"``: the paper's Remark 1 choice, ``D_ID = D_c``: models and thresholds on the same successes.
  Not covered by Proposition 1: a model's scores of its own training rollouts are lower than those of new
  successes, so the thresholds come out too low (issue #19 measured 0.78 false alarms at delta = 0.05).

A calibration declares its detectors (``settings.detectors``, :mod:`fiper_ros.core.detectors`): FIPER's
pair, or RND-OE alone (observation-only: fitted on rollouts with or without action batches; no ``R_d``, no
ACE threshold, and its alarm is RND-OE's exceedance).

A calibration directory holds ``calibration.yaml`` and the RND-OE files (``rnd_oe.npz`` and
``rnd_oe.json``). The YAML carries the split used (which rollouts fitted what), the number of rollouts
behind each threshold, a leave-one-out estimate of the false-alarm rate, and a content hash over its own
content and the network weights, so a modified or mismatched directory is refused on load. Loading needs
numpy, not torch (the scoring nodes load calibrations); fitting imports torch for RND-OE's training. A
calibration of format 1 (weights in the torch file ``rnd_oe.pt``) is refused on load with the command that
converts it, ``fiper calibrate --upgrade``, which reads it with :func:`upgrade_calibration`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fiper_ros.core.ace import action_ranges, cell_size, check_alpha
# CALIBRATION_FILE, FORMAT_VERSION and CalibrationError live in calibration_file (the YAML alone) and are used from here.
from fiper_ros.core.calibration_file import (CALIBRATION_FILE, FORMAT_VERSION, LEGACY_FORMAT_VERSION, CalibrationError,
                                             check_files, one_line, read_yaml)
from fiper_ros.core.detectors import ACE, DETECTORS, LABELS, RND_OE, SIDES, check_detectors
from fiper_ros.core.fusion import COMBINES, exceeds, fuse_declared
from fiper_ros.core.kinematics import ActionProjection, ForwardKinematics
from fiper_ros.core.profiles import Profile, get_profile
from fiper_ros.core.rnd_oe import CONFIG_FILE as RND_CONFIG_FILE
from fiper_ros.core.rnd_oe import LEGACY_WEIGHTS_FILE as RND_LEGACY_WEIGHTS_FILE
from fiper_ros.core.rnd_oe import RNDOE, ProgressCallback, RNDConfig, RNDError
from fiper_ros.core.rnd_oe import WEIGHTS_FILE as RND_WEIGHTS_FILE
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.scores import act_scores, obs_scores, rollout_positions
from fiper_ros.core.thresholds import (GUARANTEED_KINDS, Threshold, ThresholdSettings, fit_threshold,
                                      minimum_conformal_set)
from fiper_ros.core.window import MODES, aggregate

LOG = logging.getLogger(__name__)

#: Which successes fit the score models and which the thresholds (see the module docstring).
SPLITS = ("split", "cross", "same")
#: Settings only a calibration with ACE uses (with the fusion's ``combine``): an observation-only one does not
#: write them.
ACE_SETTINGS = ("alpha", "window_act", "action_dims", "control_dt", "combine")


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
        profile: ``"paper"`` or ``"reference"`` (see :mod:`fiper_ros.core.profiles`).
        extension: Threshold extension rule; ``None`` uses the profile's.
        min_support: Support rule of per-step statistics; ``None`` uses the profile's.
        band_split: Fraction of rollouts in ``I1`` of the CP band.
        min_rollouts: Fewest successful calibration rollouts accepted.
        action_dims: ``(start, stop)`` of the action channels used by ACE (see
            :class:`fiper_ros.core.kinematics.ActionProjection`); ``None``: its default.
        control_dt: Seconds per action, for ``joint_velocity`` actions.
        split: ``"split"`` (split conformal, default), ``"cross"`` (K-fold) or ``"same"`` (the paper's
            same-data calibration, not covered by Proposition 1); see the module docstring.
        conformal_fraction: With ``"split"``: the fraction of the successes in the conformal set.
        folds: With ``"cross"``: the number of folds K.
        detectors: The detectors calibrated and fused (:data:`fiper_ros.core.detectors.DETECTOR_SETS`):
            FIPER's pair (default) or ``("rnd_oe",)``, observation-only.
        shape_folds: With ``"split"``: 0 fits the thresholds' per-step shape on the fit part's curves as scored
            by the models fitted on them (in-sample); K >= 2 on cross-fitted curves, each of K folds of the fit
            part scored by models fitted on the other folds, so the shape is that of rollouts the models did
            not see, as the conformal and new rollouts are (see :func:`split_successes`).
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
    split: str = "split"
    conformal_fraction: float = 0.5
    folds: int = 5
    detectors: tuple[str, ...] = DETECTORS
    shape_folds: int = 0

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "detectors", check_detectors(self.detectors))
        except ValueError as error:
            raise CalibrationError(str(error)) from error
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
        if self.combine not in COMBINES:
            raise CalibrationError(f"unknown combine {self.combine!r}; expected one of {COMBINES}")
        if min(self.window_obs, self.window_act) < 1:
            raise CalibrationError("window sizes must be >= 1")
        if self.min_rollouts < 2:
            raise CalibrationError(f"min_rollouts must be >= 2, got {self.min_rollouts}")
        if self.seed < 0:
            raise CalibrationError(f"seed must be >= 0, got {self.seed}")
        try:
            if self.alpha is not None:
                check_alpha(self.alpha)
            self.threshold_settings()  # delta, band_split, ...: refused now, not after RND-OE's training
        except ValueError as error:
            raise CalibrationError(str(error)) from error

    @property
    def has_ace(self) -> bool:
        """Whether ACE is among the declared detectors (else: observation-only)."""
        return ACE in self.detectors

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
            band_rule=profile.band_rule,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form for YAML. The split's own settings are written only where they apply, and not at
        all for ``"same"``: calibrations written before the split existed are same-data ones and keep
        their content hash. The detectors are written only for an observation-only calibration (which
        leaves out :data:`ACE_SETTINGS`), so FIPER's calibrations keep their content hash too."""
        data = asdict(self)
        data["rnd"] = self.rnd.to_dict()
        data["action_dims"] = None if self.action_dims is None else list(self.action_dims)
        data["detectors"] = list(self.detectors)
        unused = {"split": ("folds",), "cross": ("conformal_fraction", "shape_folds"),
                  "same": ("split", "conformal_fraction", "folds", "shape_folds")}[self.split]
        unused += ("shape_folds",) if not self.shape_folds else ()  # written before it existed: the hash stays
        unused += ("detectors",) if self.has_ace else ACE_SETTINGS
        return {k: v for k, v in data.items() if k not in unused}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CalibrationSettings:
        """Inverse of :meth:`to_dict` (no ``split``: a same-data calibration; no ``detectors``: FIPER's pair)."""
        data = dict(data)
        data.setdefault("split", "same")
        data["rnd"] = RNDConfig.from_dict(data["rnd"])
        if data.get("action_dims") is not None:
            data["action_dims"] = tuple(data["action_dims"])
        if "detectors" in data:
            data["detectors"] = tuple(data["detectors"])
        return cls(**data)


@dataclass
class Calibration:
    """A fitted FIPER calibration; ``task`` is that of its rollouts ("" if they did not say).

    An observation-only calibration (``settings.detectors`` ``("rnd_oe",)``) has no ACE part: ``ranges``
    empty, ``threshold_act`` ``None``, and the action layout (``action_dim``, ``horizon``, ``exec_steps``,
    ``action_space``) 0 and "": it fits data with any action batches, or none.
    """

    settings: CalibrationSettings
    rnd: RNDOE
    ranges: np.ndarray
    threshold_obs: Threshold
    threshold_act: Threshold | None
    embedding_dim: int
    action_dim: int
    horizon: int
    exec_steps: int
    action_space: str
    num_rollouts: int
    task: str = ""
    split: dict[str, Any] = field(default_factory=dict)
    """Which successes fitted what (:class:`CalibrationSplit` by rollout id), how many rollouts each
    threshold rests on, and the guarantee; empty for calibrations written before it was recorded."""
    false_alarms: dict[str, Any] = field(default_factory=dict)
    """The leave-one-out estimate of the false-alarm rate on new successes (:func:`false_alarm_estimate`)."""

    @property
    def profile(self) -> Profile:
        """The method profile."""
        return self.settings.profile_obj

    @property
    def detectors(self) -> tuple[str, ...]:
        """The detectors this calibration declares (``settings.detectors``)."""
        return self.settings.detectors

    @property
    def has_ace(self) -> bool:
        """Whether ACE is calibrated (else: observation-only)."""
        return self.settings.has_ace

    def threshold(self, detector: str) -> Threshold:
        """The threshold of a declared detector (``"rnd_oe"``: ``gamma_O``, ``"ace"``: ``gamma_A``)."""
        if detector not in self.detectors:
            raise CalibrationError(f"detector {detector!r} is not calibrated here (detectors "
                                   f"{','.join(self.detectors)})")
        return self.threshold_obs if detector == RND_OE else self.threshold_act

    @property
    def cell(self) -> np.ndarray:
        """ACE cell size ``alpha * R_d``."""
        return cell_size(self.ranges, self.settings.resolved_alpha, self.profile.ace_binning)

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
        a task is compared only when both this calibration and the caller know it; the action layout only
        when ACE is calibrated)."""
        checked = (("embedding_dim", embedding_dim), ("action_dim", action_dim), ("horizon", horizon),
                   ("exec_steps", exec_steps))
        for name, got in checked if self.has_ace else checked[:1]:
            expected = getattr(self, name)
            if got is not None and int(got) != expected:
                raise CalibrationMismatch(name, expected, int(got))
        if self.has_ace and action_space is not None and action_space != self.action_space:
            raise CalibrationMismatch("action_space", self.action_space, action_space)
        if task and self.task and task != self.task:
            raise CalibrationMismatch("task", self.task, task)

    def _content(self) -> dict[str, Any]:
        content = {
            "format_version": FORMAT_VERSION,
            "settings": self.settings.to_dict(),
            "profile": self.settings.profile,
            "delta": float(self.settings.delta),
            "windows": {"obs": self.settings.window_obs, "act": self.settings.window_act},
            "aggregation": self.settings.aggregation,
            "threshold_kind": self.settings.threshold,
            "alpha": float(self.settings.resolved_alpha),
            "ranges": [float(r) for r in self.ranges],
            "thresholds": {"obs": self.threshold_obs.to_dict(),
                           **({"act": self.threshold_act.to_dict()} if self.threshold_act is not None else {})},
            "embedding_dim": self.embedding_dim,
            "action_dim": self.action_dim,
            "horizon": self.horizon,
            "exec_steps": self.exec_steps,
            "action_space": self.action_space,
            "num_rollouts": self.num_rollouts,
            # Only when known: calibrations written before these were recorded keep their content hash.
            **({"task": self.task} if self.task else {}),
            **({"split": self.split} if self.split else {}),
            **({"false_alarm_estimate": self.false_alarms} if self.false_alarms else {}),
        }
        if not self.has_ace:  # observation-only: no ACE entries (the detectors are in the settings)
            del content["windows"]["act"]
            for key in _ACE_CONTENT:
                del content[key]
        return content

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


#: Entries of ``calibration.yaml`` about ACE, which an observation-only calibration does not have.
_ACE_CONTENT = ("alpha", "ranges", "action_dim", "horizon", "exec_steps", "action_space")


def _content_hash(content: dict[str, Any], rnd: RNDOE) -> str:
    digest = hashlib.sha256(yaml.safe_dump(content, sort_keys=True).encode())
    digest.update(rnd.digest().encode())
    return digest.hexdigest()


def _check_description(directory: Path, embedding_dim: int, settings: CalibrationSettings) -> None:
    """``rnd_oe.json`` must describe the network ``calibration.yaml`` names (``RNDOE.save``'s fields):
    the content hash covers the YAML and the weights, this check the description."""
    path = directory / RND_CONFIG_FILE
    try:
        described = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise CalibrationError(f"{path}: unreadable ({one_line(error)})") from error
    expected = {"embedding_dim": embedding_dim, "seed": settings.seed, "config": settings.rnd.to_dict()}
    if described != expected:
        raise CalibrationError(f"{path}: does not describe the RND-OE network of {CALIBRATION_FILE} (file modified, "
                               "or files of different runs)")


def _load_rnd(directory: Path, settings: CalibrationSettings, embedding_dim: int, version: int) -> RNDOE:
    """The RND-OE model, once its description is known to be right: any failure is the weights'. The weights of
    format 1 are read with torch (imported here, for the conversion alone)."""
    legacy = version == LEGACY_FORMAT_VERSION
    path = directory / (RND_LEGACY_WEIGHTS_FILE if legacy else RND_WEIGHTS_FILE)
    try:
        if not legacy:
            return RNDOE.load(directory)
        from fiper_ros.core.rnd_train import read_legacy  # noqa: PLC0415 - torch only to convert format 1

        return read_legacy(directory, embedding_dim, settings.rnd, settings.seed)
    except Exception as error:  # noqa: BLE001 - numpy, zipfile and torch raise OSError, ValueError, pickle errors...
        cause = error.__cause__ if isinstance(error, RNDError) and error.__cause__ is not None else error
        detail = re.split(r"(?<=\.)\s|\n", str(cause).strip(), maxsplit=1)[0]
        raise CalibrationError(f"{path}: not readable RND-OE weights (damaged, or not written by fiper calibrate: "
                               f"{type(cause).__name__}{': ' + detail if detail else ''})") from error


def load_calibration(directory: str | Path) -> Calibration:
    """Read a calibration directory written by :meth:`Calibration.save`.

    Raises :class:`CalibrationError` with one line naming the file for a missing directory or file, a
    file that does not parse, an unknown format version (format 1: with the command that converts it), a
    missing or malformed entry, a modified file (content hash, RND-OE description) and weights that do not
    load.
    """
    return _read(Path(directory), FORMAT_VERSION)


def upgrade_calibration(directory: str | Path) -> Calibration:
    """Read a calibration of format 1 (weights in ``rnd_oe.pt``; imports torch), checked like
    :func:`load_calibration` checks one of the current format (its content hash included); saved, it is of
    the current format, with the same thresholds, weights and scores."""
    return _read(Path(directory), LEGACY_FORMAT_VERSION)


def _read(directory: Path, version: int) -> Calibration:
    """The calibration in ``directory``, of format ``version``."""
    path = directory / CALIBRATION_FILE
    check_files(directory, (CALIBRATION_FILE,))
    content = read_yaml(path, version)
    weights = RND_LEGACY_WEIGHTS_FILE if version == LEGACY_FORMAT_VERSION else RND_WEIGHTS_FILE
    check_files(directory, (RND_CONFIG_FILE, weights))
    try:
        settings = CalibrationSettings.from_dict(content["settings"])
        has_ace = settings.has_ace
        fields = {
            "ranges": np.asarray(content["ranges"] if has_ace else [], dtype=np.float64),
            "threshold_obs": Threshold.from_dict(content["thresholds"]["obs"]),
            "threshold_act": Threshold.from_dict(content["thresholds"]["act"]) if has_ace else None,
            "embedding_dim": int(content["embedding_dim"]),
            "action_dim": int(content["action_dim"]) if has_ace else 0,
            "horizon": int(content["horizon"]) if has_ace else 0,
            "exec_steps": int(content["exec_steps"]) if has_ace else 0,
            "action_space": str(content["action_space"]) if has_ace else "",
            "num_rollouts": int(content["num_rollouts"]),
            "task": str(content.get("task", "")),
            "split": dict(content.get("split", {})),
            "false_alarms": dict(content.get("false_alarm_estimate", {})),
        }
    except KeyError as error:
        raise CalibrationError(f"{path}: missing entry {error}") from error
    except (TypeError, ValueError) as error:  # ThresholdError, RNDConfig and settings values
        raise CalibrationError(f"{path}: malformed entry ({one_line(error)})") from error
    _check_description(directory, fields["embedding_dim"], settings)
    rnd = _load_rnd(directory, settings, fields["embedding_dim"], version)
    calibration = Calibration(settings=settings, rnd=rnd, **fields)
    stored = content.pop("content_hash", None)
    # The fields must give back the file's content (of the file's version) and its hash.
    rebuilt = {**calibration._content(), "format_version": version}  # noqa: SLF001
    if stored != _content_hash(content, rnd) or stored != _content_hash(rebuilt, rnd):
        raise CalibrationError(f"{path}: content hash mismatch (file or weights modified, or files of different runs)")
    return calibration


#: The layout fields of :func:`_layout`; an observation-only calibration has the first alone.
_LAYOUT = ("embedding_dim", "action_dim", "horizon", "exec_steps", "action_space")


def _layout(rollout: Rollout, has_ace: bool) -> tuple[int, int, int, int, str]:
    """``(embedding_dim, action_dim, horizon, exec_steps, action_space)`` of a rollout (without ACE: the action
    fields 0 and "", whatever the rollout holds)."""
    if not has_ace:
        return rollout.embeddings.shape[1], 0, 0, 0, ""
    if rollout.actions is None:
        raise CalibrationError(f"rollout {rollout.rollout_id!r} has no action batches, which ACE needs: calibrate "
                               "RND-OE alone for an observation-only calibration (detectors rnd_oe, fiper calibrate "
                               "--detectors rnd_oe)")
    shape = rollout.actions.shape
    return rollout.embeddings.shape[1], shape[3], shape[2], rollout.exec_steps, rollout.action_space


def _task_of(rollouts: Sequence[Rollout]) -> str:
    """The one task the rollouts name ("" if none does); rollouts of several tasks are refused."""
    tasks = sorted({r.task for r in rollouts if r.task})
    if len(tasks) > 1:
        raise CalibrationError(f"calibration rollouts of several tasks ({', '.join(tasks)}): calibrate each task "
                               "on its own")
    return tasks[0] if tasks else ""


def _check_consistent(rollouts: Sequence[Rollout], has_ace: bool) -> tuple[int, int, int, int, str]:
    expected = _layout(rollouts[0], has_ace)
    for rollout in rollouts[1:]:
        for name, want, have in zip(_LAYOUT, expected, _layout(rollout, has_ace)):
            if want != have:
                raise CalibrationMismatch(f"{name} of rollout {rollout.rollout_id!r}", want, have)
    return expected


@dataclass(frozen=True)
class CalibrationSplit:
    """Which successful calibration rollouts (indices into them) fitted what."""

    mode: str
    fit: tuple[int, ...]
    """Fitted RND-OE and ``R_d`` (and, with ``"split"``, the thresholds' per-step shape)."""
    conformal: tuple[int, ...]
    """Fitted the thresholds (their conformal quantiles)."""
    folds: tuple[tuple[int, ...], ...] = ()
    """With ``"cross"``: the K folds; fold ``k``'s curves come from models fitted without it."""
    shape_folds: tuple[tuple[int, ...], ...] = ()
    """With ``"split"`` and ``shape_folds`` K >= 2: K folds of :attr:`fit`; the shape curves of a fold's
    rollouts come from models fitted on the rest of the fit part (empty: in-sample shape curves)."""


def split_successes(count: int, settings: CalibrationSettings) -> CalibrationSplit:
    """The split of ``count`` successes that ``settings`` asks for, seeded by ``settings.seed``."""
    everything = tuple(range(count))
    if settings.split == "same":
        return CalibrationSplit("same", everything, everything)
    order = np.random.default_rng([settings.seed, 19]).permutation(count)  # not the CP band's stream
    if settings.split == "cross":
        if count < settings.folds:
            raise CalibrationError(f"{settings.folds}-fold cross-fitting needs at least {settings.folds} successes, "
                                   f"got {count}")
        folds = tuple(tuple(sorted(int(i) for i in fold)) for fold in np.array_split(order, settings.folds))
        return CalibrationSplit("cross", everything, everything, folds)
    conformal = min(max(round(settings.conformal_fraction * count), 1), count - 1)
    fit = tuple(sorted(int(i) for i in order[conformal:]))
    shape_folds: tuple[tuple[int, ...], ...] = ()
    if settings.shape_folds:
        if len(fit) < settings.shape_folds:
            raise CalibrationError(f"{settings.shape_folds}-fold cross-fitted shapes need at least "
                                   f"{settings.shape_folds} successes in the fit part, got {len(fit)}")
        shuffled = np.random.default_rng([settings.seed, 29]).permutation(np.array(fit))
        shape_folds = tuple(tuple(sorted(int(i) for i in fold))
                            for fold in np.array_split(shuffled, settings.shape_folds))
    return CalibrationSplit("split", fit, tuple(sorted(int(i) for i in order[:conformal])), shape_folds=shape_folds)


@dataclass(frozen=True)
class _Fitted:
    """Score models fitted on some rollouts: RND-OE and the ACE cell (empty without ACE)."""

    rnd: RNDOE
    ranges: np.ndarray
    cell: np.ndarray


#: Aggregated curves (eqs. 2, 5) per declared detector, one per rollout.
Curves = dict[str, list[np.ndarray]]


def _fit_models(fit: Sequence[Rollout], extra_ranges: Sequence[Rollout], settings: CalibrationSettings,
                projection: ActionProjection | None, progress: ProgressCallback | None) -> _Fitted:
    # Positions are recomputed when scoring instead of kept: a task with B = 256 holds hundreds of MB of them.
    ranges = (action_ranges(rollout_positions(r, projection) for r in [*fit, *extra_ranges]) if settings.has_ace
              else np.zeros(0))
    from fiper_ros.core.rnd_train import fit_rnd  # noqa: PLC0415 - torch only where RND-OE is trained, not to load

    rnd = fit_rnd(np.concatenate([r.embeddings for r in fit]), settings.rnd, settings.seed, progress)
    return _Fitted(rnd, ranges, cell_size(ranges, settings.resolved_alpha, settings.profile_obj.ace_binning))


def _curves(models: _Fitted, rollouts: Sequence[Rollout], settings: CalibrationSettings,
            projection: ActionProjection | None) -> Curves:
    """The aggregated curves (eqs. 2, 5) of ``rollouts`` under ``models``, per declared detector."""
    profile, mode = settings.profile_obj, settings.aggregation
    curves = {RND_OE: [aggregate(obs_scores(models.rnd, r.embeddings, profile), mode, settings.window_obs)
                       for r in rollouts]}
    if settings.has_ace:
        curves[ACE] = [aggregate(act_scores(rollout_positions(r, projection), models.cell, profile), mode,
                                 settings.window_act) for r in rollouts]
    return curves


def _shape_curves(models: _Fitted, good: Sequence[Rollout], split: CalibrationSplit, failed: Sequence[Rollout],
                  settings: CalibrationSettings, projection: ActionProjection | None) -> Curves:
    """The fit part's curves for the thresholds' shape, in the order of ``split.fit``: scored by ``models`` (fitted
    on them, in-sample) or, with shape folds, each fold by models fitted on the rest of the fit part."""
    if not split.shape_folds:
        return _curves(models, [good[i] for i in split.fit], settings, projection)
    position = {index: n for n, index in enumerate(split.fit)}
    shape: Curves = {name: [np.empty(0)] * len(split.fit) for name in settings.detectors}
    for fold in split.shape_folds:
        rest = [good[i] for i in split.fit if i not in fold]
        fold_curves = _curves(_fit_models(rest, failed, settings, projection, None), [good[i] for i in fold], settings,
                              projection)
        for name, own in fold_curves.items():
            for i, curve in zip(fold, own):
                shape[name][position[i]] = curve
    return shape


def _check_finite(threshold: Threshold, name: str, split: CalibrationSplit, settings: CalibrationSettings,
                  successes: int) -> None:
    """Refuse a threshold that is +inf somewhere, naming the fewest successes that would do."""
    if np.isfinite(threshold.values).all():
        return
    need = minimum_conformal_set(settings.delta)
    have = int(threshold.params.get("m2", threshold.params.get("m", 0)))
    # The conformal scores are a share of the successes: search the smallest count that gives enough.
    smallest = next(m for m in range(successes + 1, 1_000_000) if _conformal_count(m, split.mode, settings) >= need)
    raise CalibrationError(
        f"the {name} threshold ({settings.threshold}) is +inf: its conformal quantile at delta={settings.delta:g} "
        f"needs at least {need} rollouts, this calibration gives it {have} of {successes} successes; calibrate on "
        f"at least {smallest} successful rollouts (or raise --delta)")


def _conformal_count(successes: int, mode: str, settings: CalibrationSettings) -> int:
    """How many scores a threshold's conformal quantile gets from ``successes`` successes."""
    conformal = successes if mode != "split" else min(max(round(settings.conformal_fraction * successes), 1),
                                                         successes - 1)
    if settings.threshold in ("cp_band", "cp_scaled", "gaussian") and mode != "split":
        conformal -= min(max(round(settings.band_split * conformal), 1), conformal - 1)  # the band's own I2
    return conformal


def _fit_thresholds(curves: Curves, shape: Curves | None, settings: ThresholdSettings) -> dict[str, Threshold]:
    return {name: fit_threshold(own, settings, None if shape is None else shape[name]) for name, own in curves.items()}


def false_alarm_estimate(curves: Curves, shape: Curves | None, settings: CalibrationSettings) -> dict[str, Any]:
    """Leave-one-out estimate of the false-alarm rate on new successes (eq. 7 over the declared detectors at
    any step, :func:`~fiper_ros.core.fusion.fuse_declared`): each conformal rollout judged by thresholds
    fitted without it. Its curves are held out from the score models with ``"split"`` and ``"cross"``; with
    ``"same"`` the models saw it, so the estimate is optimistic."""
    threshold_settings = settings.threshold_settings()
    n = len(curves[RND_OE])
    alarms = 0
    for j in range(n):
        others = {name: [own[i] for i in range(n) if i != j] for name, own in curves.items()}
        thresholds = _fit_thresholds(others, shape, threshold_settings)
        exceeded = [exceeds(curves[d][j], thresholds[d].over(curves[d][j].shape[0])) for d in settings.detectors]
        alarms += bool(np.any(fuse_declared(exceeded, settings.combine)))
    rate = alarms / n
    return {"method": "leave-one-out over the conformal rollouts", "rollouts": n, "false_alarms": alarms,
            "rate": rate, "standard_error": math.sqrt(rate * (1.0 - rate) / n),
            "held_out_from_models": settings.split != "same"}


def _or_of_two(settings: CalibrationSettings) -> bool:
    """Whether an alarm is either of two thresholds' (OR of RND-OE and ACE; not RND-OE alone)."""
    return settings.has_ace and settings.combine == "or"


def promised_rate(settings: CalibrationSettings) -> float:
    """The bound on the false-alarm rate over new successful rollouts that Prop. 1 gives these settings
    (if their split and threshold kind are covered at all, see :func:`guarantee`): ``delta`` with AND (an
    alarm needs both detectors' thresholds exceeded, each at most ``delta`` of the time) and with RND-OE
    alone (its one threshold), ``2 delta`` with OR (either of two thresholds at ``delta`` each: the union
    bound)."""
    return settings.delta * (2.0 if _or_of_two(settings) else 1.0)


def guarantee(settings: CalibrationSettings) -> str:
    """What the calibration promises about false alarms on new successful rollouts, in one sentence."""
    if settings.threshold not in GUARANTEED_KINDS:
        return (f"none: a {settings.threshold} threshold bounds each step, not a whole rollout "
                "(docs/method.md, 'What each threshold guarantees')")
    rate = promised_rate(settings)
    how = "" if not _or_of_two(settings) else (f"; OR of two thresholds at delta {settings.delta:g} each: the union "
                                               f"bound, calibrate at --delta {settings.delta / 2:g} for {settings.delta:g}")
    if settings.split == "split":
        return (f"at most {rate:g} of new successful rollouts alarmed (Proposition 1: split conformal, "
                f"models and thresholds on disjoint successes{how})")
    if settings.split == "cross":
        return (f"about {rate:g} (cross-fitted: approximate, the deployed model saw every calibration "
                f"rollout; no finite-sample guarantee{how})")
    return "not covered by Proposition 1 (models and thresholds on the same successes, --same-data)"


def calibrate(
    rollouts: Sequence[Rollout],
    settings: CalibrationSettings | None = None,
    fk: ForwardKinematics | None = None,
    progress: ProgressCallback | None = None,
    refuse_infinite: bool = True,
) -> Calibration:
    """Fit RND-OE, ``R_d`` and both thresholds from calibration rollouts, split as ``settings.split`` says.

    Only rollouts with ``success is True`` are used, except that the ``"reference"`` profile takes
    ``R_d`` over the failed rollouts too, as the authors' code does.

    Args:
        rollouts: Calibration rollouts.
        settings: Hyperparameters; defaults to :class:`CalibrationSettings`.
        fk: Forward kinematics for joint-space actions.
        progress: Called after every RND-OE training epoch.
        refuse_infinite: Raise :class:`CalibrationError` for a threshold that is +inf (too few conformal
            rollouts for delta), naming the fewest successes that would do; False keeps it (the
            evaluation shows such cells instead of using them).
    """
    settings = settings or CalibrationSettings()
    good = successful(list(rollouts))
    if len(good) < settings.min_rollouts:
        raise CalibrationError(
            f"calibration needs at least {settings.min_rollouts} successful rollouts, got {len(good)} "
            f"(of {len(rollouts)} given)"
        )
    embedding_dim, action_dim, horizon, exec_steps, action_space = _check_consistent(list(rollouts), settings.has_ace)
    task = _task_of(rollouts)
    projection = ActionProjection(action_space, settings.action_dims, fk, settings.control_dt) if settings.has_ace \
        else None
    failed = [r for r in rollouts if r.success is not True] if settings.profile_obj.ranges_from_all else []
    split = split_successes(len(good), settings)
    fit = [good[i] for i in split.fit]
    LOG.info("calibrating on %d successful rollouts (%s split: %d fit, %d conformal)", len(good), split.mode,
             len(split.fit), len(split.conformal))
    models = _fit_models(fit, failed, settings, projection, progress)
    shape = None
    if split.mode == "same":
        curves = _curves(models, good, settings, projection)
    elif split.mode == "split":
        shape = _shape_curves(models, good, split, failed, settings, projection)
        curves = _curves(models, [good[i] for i in split.conformal], settings, projection)
    else:  # cross: each fold scored by models fitted without it, in the order of the successes
        curves = {name: [np.empty(0)] * len(good) for name in settings.detectors}
        for fold in split.folds:
            rest = [good[i] for i in range(len(good)) if i not in fold]
            fold_curves = _curves(_fit_models(rest, failed, settings, projection, None), [good[i] for i in fold],
                                  settings, projection)
            for name, own in fold_curves.items():
                for i, curve in zip(fold, own):
                    curves[name][i] = curve
    thresholds = _fit_thresholds(curves, shape, settings.threshold_settings())
    if refuse_infinite:
        for name, threshold in thresholds.items():
            _check_finite(threshold, LABELS[name], split, settings, len(good))
    ids = [str(r.rollout_id) for r in good]
    record = {"mode": split.mode, "seed": settings.seed, "successes": len(good),
              "fit": [ids[i] for i in split.fit], "conformal": [ids[i] for i in split.conformal],
              **({"folds": [[ids[i] for i in fold] for fold in split.folds]} if split.folds else {}),
              **({"shape_folds": [[ids[i] for i in fold] for fold in split.shape_folds]} if split.shape_folds else {}),
              "behind_thresholds": {SIDES[name]: _behind(t) for name, t in thresholds.items()},
              "guarantee": guarantee(settings)}
    return Calibration(
        settings=settings,
        rnd=models.rnd,  # with "cross", fitted on every success: the deployed model
        ranges=models.ranges,
        threshold_obs=thresholds[RND_OE],
        threshold_act=thresholds.get(ACE),
        embedding_dim=embedding_dim,
        action_dim=action_dim,
        horizon=horizon,
        exec_steps=exec_steps,
        action_space=action_space,
        num_rollouts=len(good),
        task=task,
        split=record,
        false_alarms=false_alarm_estimate(curves, shape, settings),
    )


def _behind(threshold: Threshold) -> dict[str, int]:
    """How many rollouts a threshold's shape and conformal quantile rest on."""
    params = threshold.params
    if "m2" in params:
        return {"shape": int(params["m1"]), "conformal": int(params["m2"])}
    return {"conformal": int(params["m"])}
