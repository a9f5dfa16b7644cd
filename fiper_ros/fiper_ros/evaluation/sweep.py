"""The configuration sweep: first-alarm steps of every method for every window, threshold and delta.

For one task and seed, every score stream is padded to ``[rollouts, T_max]`` with NaN (NaN never
exceeds a threshold, so padding raises no alarm) and aggregated for all windows at once: the window
``w`` sum is the ``w - 1`` sum plus the scores shifted by ``w - 1`` steps, which adds the same float64
numbers in the same order as :func:`fiper_ros.core.window.windowed`, so every curve is bit-identical
to the core's. The cumulative sum (``w = inf``, label ``"cum"``) is ``np.cumsum`` as in the core.
Single-step aggregation is ``w = 1``.

Thresholds are fitted on the successful calibration rollouts' curves with the core's rules
(:mod:`.threshold_grid`, all deltas at once) and extended with :meth:`Threshold.over`; alarms are the
core's strict ``eta > gamma`` (:func:`fiper_ros.core.fusion.exceeds`), FIPER fuses the RND-OE and
ACE decisions with :func:`fiper_ros.core.fusion.fuse`, and the first alarm of every rollout is kept
(-1 for none), vectorised over kinds, deltas and rollouts.

FIPER's ``(w_O, w_A)`` grid (``pairs``): ``"diagonal"`` (``w_O = w_A``, every window), ``"coarse"``
(the diagonal plus all pairs of :data:`COARSE_WINDOWS`, the default) or ``"full"`` (all pairs; slow).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from fiper_ros.core.fusion import COMBINES, exceeds, fuse
from fiper_ros.core.thresholds import ThresholdSettings
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.threshold_grid import GRID_KINDS, fit_threshold_grid

DELTAS: tuple[float, ...] = tuple(round(0.01 * i, 2) for i in range(1, 11))
CUMULATIVE = "cum"
COARSE_WINDOWS = (1, 2, 3, 5, 8, 10, 15, 20, 25, 30, 40, 50)
PAIR_GRIDS = ("diagonal", "coarse", "full")
FIPER = "fiper"
FIPER_STREAMS = ("rnd_oe", "ace")


@dataclass(frozen=True)
class SweepSettings:
    """What the sweep covers (defaults: the paper's grid plus the cumulative sum)."""

    windows: tuple[int, ...] = tuple(range(1, 51))
    cumulative: bool = True
    deltas: tuple[float, ...] = DELTAS
    kinds: tuple[str, ...] = ("cp_band", "cp_constant", "time_varying")
    combines: tuple[str, ...] = COMBINES
    pairs: str = "coarse"

    def __post_init__(self) -> None:
        if not self.windows or min(self.windows) < 1:
            raise ValueError(f"windows must be integers >= 1, got {self.windows}")
        if any(kind not in GRID_KINDS for kind in self.kinds):
            raise ValueError(f"threshold kinds must be among {GRID_KINDS}, got {self.kinds}")
        if any(combine not in COMBINES for combine in self.combines):
            raise ValueError(f"combines must be among {COMBINES}, got {self.combines}")
        if self.pairs not in PAIR_GRIDS:
            raise ValueError(f"pairs must be one of {PAIR_GRIDS}, got {self.pairs!r}")
        if any(not 0.0 < d < 1.0 for d in self.deltas):
            raise ValueError(f"deltas must be in (0, 1), got {self.deltas}")

    def labels(self) -> list[str]:
        """Window labels in sweep order: ``"1"``, ``"2"``, ... and ``"cum"``."""
        return [str(w) for w in sorted(set(self.windows))] + ([CUMULATIVE] if self.cumulative else [])

    def fiper_pairs(self) -> list[tuple[str, str]]:
        """FIPER's ``(w_O, w_A)`` label pairs."""
        labels = self.labels()
        diagonal = [(label, label) for label in labels]
        if self.pairs == "diagonal":
            return diagonal
        grid = labels if self.pairs == "full" else [lb for lb in labels if lb == CUMULATIVE or int(lb) in COARSE_WINDOWS]
        pairs = [(a, b) for a in grid for b in grid]
        return pairs + [p for p in diagonal if p not in pairs]


@dataclass(frozen=True)
class Group:
    """One configuration without its delta: method, window label, threshold kind, FIPER combine."""

    method: str
    window: str
    kind: str
    combine: str = ""

    @property
    def aggregation(self) -> str:
        """``"cumulative"`` or ``"window"``."""
        return "cumulative" if CUMULATIVE in self.window else "window"

    def windows(self) -> tuple[int | None, int | None]:
        """``(w_O, w_A)`` for FIPER, ``(w, None)`` otherwise; ``None`` for the cumulative sum."""
        parts = [None if part == CUMULATIVE else int(part) for part in self.window.split("/")]
        return (parts[0], parts[1]) if len(parts) == 2 else (parts[0], None)


def padded(curves: list[np.ndarray]) -> np.ndarray:
    """``[len(curves), max length]`` float64, NaN after each curve's end."""
    out = np.full((len(curves), max(c.shape[0] for c in curves)), np.nan)
    for i, curve in enumerate(curves):
        out[i, : curve.shape[0]] = curve
    return out


def aggregated(scores: np.ndarray, settings: SweepSettings) -> Iterator[tuple[str, np.ndarray]]:
    """``(label, eta)`` for every window label of ``settings`` over padded scores ``[N, T]``."""
    wanted = set(settings.windows)
    eta = scores.copy()
    for w in range(1, max(wanted) + 1):
        if w > 1 and w - 1 < scores.shape[1]:
            eta[:, w - 1 :] += scores[:, : -(w - 1)]
        if w in wanted:
            yield str(w), eta
    if settings.cumulative:
        yield CUMULATIVE, np.cumsum(scores, axis=1)


def first_alarms(exceeded: np.ndarray) -> np.ndarray:
    """First ``True`` along the last axis (the core's ``first_alarm``), -1 where there is none."""
    return np.where(exceeded.any(axis=-1), exceeded.argmax(axis=-1), -1).astype(np.int32)


def _stream_alarms(
    stream: StreamScores, settings: SweepSettings, base: ThresholdSettings, keep: set[str]
) -> Iterator[tuple[str, np.ndarray, np.ndarray | None]]:
    """Per window label: first alarms ``[K, D, N]`` and, for labels in ``keep``, the exceedances."""
    lengths = [c.shape[0] for c in stream.calibration]
    test = padded(stream.test)
    calibration_windows = aggregated(padded(stream.calibration), settings)
    for (label, eta_test), (_, eta_cal) in zip(aggregated(test, settings), calibration_windows):
        curves = [eta_cal[i, :length] for i, length in enumerate(lengths)]
        grid = fit_threshold_grid(curves, settings.kinds, settings.deltas, base)
        gamma = np.stack([[t.over(test.shape[1]) for t in grid[kind]] for kind in settings.kinds])
        exceeded = np.asarray(exceeds(eta_test[None, None], gamma[:, :, None, :]), dtype=bool)
        yield label, first_alarms(exceeded), exceeded if label in keep else None


def sweep_task(
    streams: dict[str, StreamScores], methods: list[str], settings: SweepSettings, base: ThresholdSettings
) -> tuple[list[Group], np.ndarray]:
    """Groups and first-alarm steps ``[groups, deltas, test rollouts]`` of one task and seed.

    ``base`` carries the profile's threshold rules and the seed of the CP band split.
    """
    groups: list[Group] = []
    alarms: list[np.ndarray] = []
    pairs = settings.fiper_pairs() if FIPER in methods else []
    kept: dict[str, dict[str, np.ndarray]] = {s: {} for s in FIPER_STREAMS}
    for name, stream in streams.items():
        keep = {pair[FIPER_STREAMS.index(name)] for pair in pairs} if name in FIPER_STREAMS else set()
        for label, first, exceeded in _stream_alarms(stream, settings, base, keep):
            if exceeded is not None:
                kept[name][label] = exceeded
            if name in methods:
                groups.extend(Group(name, label, kind) for kind in settings.kinds)
                alarms.extend(first)
    for obs_label, act_label in pairs:
        for combine in settings.combines:
            fused = np.asarray(fuse(kept["rnd_oe"][obs_label], kept["ace"][act_label], combine), dtype=bool)
            groups.extend(Group(FIPER, f"{obs_label}/{act_label}", kind, combine) for kind in settings.kinds)
            alarms.extend(first_alarms(fused))
    return groups, np.stack(alarms)
