"""The configuration sweep: first-alarm steps of every method for every window, threshold and delta.

For one task and seed, every score stream is padded to ``[rollouts, T_max]`` with NaN (NaN never
exceeds a threshold, so padding raises no alarm) and aggregated for all windows at once: the window
``w`` sum is the ``w - 1`` sum plus the scores shifted by ``w - 1`` steps, which adds the same float64
numbers in the same order as :func:`fiper_ros.core.window.windowed`, so every curve is bit-identical
to the core's. The cumulative sum (``w = inf``, label ``"cum"``) is ``np.cumsum`` as in the core.
Single-step aggregation is ``w = 1``. Max-pooling over ``w`` steps (label ``"max<w>"``, the core's mode
``"max"``) is the running maximum of the same shifted scores (a maximum has no rounding).

Thresholds are fitted with the core's rules (:mod:`.threshold_grid`, all deltas at once) on the
conformal part's curves, with the fit part's curves as the shape (``shape_curves``) where the split has
one (:class:`fiper_ros.evaluation.cache.StreamScores`), exactly as :func:`fiper_ros.core.calibration.calibrate`
does, and extended with :meth:`Threshold.over`; alarms are the core's strict ``eta > gamma``
(:func:`fiper_ros.core.fusion.exceeds`), FIPER fuses the RND-OE and ACE decisions with
:func:`fiper_ros.core.fusion.fuse`, and the first alarm of every rollout is kept (-1 for none),
vectorised over kinds, deltas and rollouts. A threshold that is +inf (a conformal quantile of too few
rollouts for its delta) is recorded (:attr:`TaskSweep.infinite`) with the number of rollouts behind
it, so that no table averages or selects it.

A method with a single configuration (:attr:`fiper_ros.evaluation.methods.Method.fixed`, the
elapsed-time baseline) gets only that one, whatever the grid.

On request (``thresholds``, for ``fiper evaluate --dump``) every configuration's thresholds over the test steps
are kept too (:attr:`TaskSweep.thresholds`): the arrays the alarms were decided with, no extra work.

FIPER's ``(w_O, w_A)`` grid (``pairs``): ``"diagonal"`` (``w_O = w_A``, every window), ``"coarse"``
(the diagonal plus all pairs of :data:`COARSE_WINDOWS`, the default) or ``"full"`` (all pairs; slow).

The promise of an OR (``or_promise``, :data:`~fiper_ros.core.auto.PROMISES`): ``"entry"`` (the paper's, the
default) sets both of FIPER's thresholds at delta, so the OR promises ``2 delta`` (Proposition 1 and the union
bound); ``"delta"`` sets each at ``delta / 2`` (thresholds fitted at the halved deltas too), so every configuration
of the sweep, OR included, is at promise delta in the column of delta: tables compare them at equal promise.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from fiper_ros.core.auto import DELTA_PROMISE, ENTRY_PROMISE, PROMISES
from fiper_ros.core.combine_mode import COMBINES
from fiper_ros.core.fusion import Combine, exceeds, fuse
from fiper_ros.core.thresholds import ThresholdSettings
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.errors import SettingsError
from fiper_ros.evaluation.methods import METHODS
from fiper_ros.evaluation.threshold_grid import GRID_KINDS, fit_threshold_grid

DELTAS: tuple[float, ...] = tuple(round(0.01 * i, 2) for i in range(1, 11))
CUMULATIVE = "cum"
#: The label prefix of a max-pooled window (``"max5"``).
MAX_POOL = "max"
#: The max-pooled windows swept by default.
MAX_POOL_WINDOWS = (2, 3, 5, 8, 10, 15, 20, 30)
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
    kinds: tuple[str, ...] = ("cp_band", "cp_constant", "time_varying", "cp_scaled")
    combines: tuple[str, ...] = COMBINES
    pairs: str = "coarse"
    max_pool: tuple[int, ...] = MAX_POOL_WINDOWS
    or_promise: str = ENTRY_PROMISE
    """What an OR of ``N`` thresholds promises in the column of delta (:data:`~fiper_ros.core.auto.PROMISES`):
    ``"entry"``, each threshold at delta (promise ``N delta``); ``"delta"``, each at ``delta / N`` (promise delta)."""

    def __post_init__(self) -> None:
        if not self.windows or min(self.windows) < 1:
            raise SettingsError(f"windows must be integers >= 1, got {self.windows}")
        if self.max_pool and min(self.max_pool) < 2:
            raise SettingsError(f"max-pooled windows must be integers >= 2 (1 is the single step), got {self.max_pool}")
        if any(kind not in GRID_KINDS for kind in self.kinds):
            raise SettingsError(f"threshold kinds must be among {GRID_KINDS}, got {self.kinds}")
        if any(combine not in COMBINES for combine in self.combines):
            raise SettingsError(f"combines must be among {COMBINES}, got {self.combines}")
        if self.pairs not in PAIR_GRIDS:
            raise SettingsError(f"pairs must be one of {PAIR_GRIDS}, got {self.pairs!r}")
        if not self.deltas or any(not 0.0 < d < 1.0 for d in self.deltas):
            raise SettingsError(f"deltas must be in (0, 1), at least one, got {self.deltas}")
        if self.or_promise not in PROMISES:
            raise SettingsError(f"or_promise must be one of {', '.join(PROMISES)}, got {self.or_promise!r}")

    def threshold_delta(self, delta: float, combine: str, detectors: int) -> float:
        """The delta each of ``detectors`` thresholds combined by ``combine`` is calibrated at in the column of
        ``delta``: at :attr:`or_promise` ``"delta"``, ``delta`` over the combine's promised multiple
        (:meth:`~fiper_ros.core.fusion.Combine.promised_multiple`: ``N`` for an OR of ``N``), else ``delta``."""
        if self.or_promise == DELTA_PROMISE:
            return delta / Combine.parse(combine).promised_multiple(detectors)
        return delta

    def labels(self) -> list[str]:
        """Window labels in sweep order: ``"1"``, ``"2"``, ..., ``"cum"``, then ``"max2"``, ``"max3"``, ..."""
        sums = [str(w) for w in sorted(set(self.windows))] + ([CUMULATIVE] if self.cumulative else [])
        return sums + [f"{MAX_POOL}{w}" for w in sorted(set(self.max_pool))]

    def fiper_pairs(self) -> list[tuple[str, str]]:
        """FIPER's ``(w_O, w_A)`` label pairs (max-pooled windows only on the diagonal)."""
        diagonal = [(label, label) for label in self.labels()]
        labels = [label for label in self.labels() if not label.startswith(MAX_POOL)]
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
        """``"cumulative"``, ``"max"`` (max-pooled) or ``"window"``: the core's aggregation mode."""
        if CUMULATIVE in self.window:
            return "cumulative"
        return "max" if self.window.startswith(MAX_POOL) else "window"

    def windows(self) -> tuple[int | None, int | None]:
        """``(w_O, w_A)`` for FIPER, ``(w, None)`` otherwise; ``None`` for the cumulative sum."""
        parts = [None if part == CUMULATIVE else int(part.removeprefix(MAX_POOL)) for part in self.window.split("/")]
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
    if settings.max_pool:
        pooled = scores.copy()
        for w in range(2, max(settings.max_pool) + 1):
            if w - 1 < scores.shape[1]:
                np.maximum(pooled[:, w - 1:], scores[:, : -(w - 1)], out=pooled[:, w - 1:])
            if w in settings.max_pool:
                yield f"{MAX_POOL}{w}", pooled


def first_alarms(exceeded: np.ndarray) -> np.ndarray:
    """First ``True`` along the last axis (the core's ``first_alarm``), -1 where there is none."""
    return np.where(exceeded.any(axis=-1), exceeded.argmax(axis=-1), -1).astype(np.int32)


@dataclass
class LabelAlarms:
    """One window label of one stream: per kind and delta, the first alarms and the thresholds' state."""

    label: str
    first: np.ndarray
    """First alarm steps ``[kinds, deltas, test rollouts]`` (-1: none)."""
    gamma: np.ndarray
    """The thresholds over the test steps ``[kinds, deltas, T]`` (``T``: the longest test rollout)."""
    exceeded: np.ndarray | None
    """``eta > gamma`` ``[kinds, deltas, test rollouts, T]``, kept only for the labels FIPER fuses."""
    infinite: np.ndarray
    """``[kinds, deltas]``: the threshold is +inf somewhere (it never alarms there)."""
    conformal: np.ndarray
    """``[kinds]``: how many rollouts the threshold's quantile is taken over (``M``, or ``M2`` of a band)."""


def _stream_alarms(
    stream: StreamScores, settings: SweepSettings, base: ThresholdSettings, keep: set[str]
) -> Iterator[LabelAlarms]:
    """Per window label of ``settings``: the first alarms, the kept exceedances and the thresholds' state."""
    conformal_lengths = [c.shape[0] for c in stream.conformal]
    fit_lengths = [c.shape[0] for c in stream.fit] if stream.fit is not None else []
    test = padded(stream.test)
    conformal_windows = aggregated(padded(stream.conformal), settings)
    fit_windows = aggregated(padded(stream.fit), settings) if stream.fit is not None else None
    for label, eta_test in aggregated(test, settings):
        _, eta_conformal = next(conformal_windows)
        curves = [eta_conformal[i, :length] for i, length in enumerate(conformal_lengths)]
        shape = None
        if fit_windows is not None:
            _, eta_fit = next(fit_windows)
            shape = [eta_fit[i, :length] for i, length in enumerate(fit_lengths)]
        grid = fit_threshold_grid(curves, settings.kinds, settings.deltas, base, shape)
        gamma = np.stack([[t.over(test.shape[1]) for t in grid[kind]] for kind in settings.kinds])
        exceeded = np.asarray(exceeds(eta_test[None, None], gamma[:, :, None, :]), dtype=bool)
        infinite = np.array([[bool(np.isinf(t.values).any()) for t in grid[kind]] for kind in settings.kinds])
        behind = np.array([int(grid[kind][0].params.get("m2", grid[kind][0].params["m"])) for kind in settings.kinds])
        yield LabelAlarms(label, first_alarms(exceeded), gamma, exceeded if label in keep else None, infinite, behind)


@dataclass
class TaskSweep:
    """Every configuration of one task and seed."""

    groups: list[Group]
    alarms: np.ndarray
    """First alarm steps ``[groups, deltas, test rollouts]`` (-1: none)."""
    infinite: np.ndarray
    """``[groups, deltas]``: a threshold of the configuration is +inf (FIPER: either one)."""
    conformal: np.ndarray
    """``[groups]``: rollouts behind the configuration's conformal quantile (FIPER: the fewer of its two)."""
    thresholds: list[np.ndarray] | None = None
    """Kept on request: per group, its detectors' thresholds over the test steps ``[deltas, detectors, T]`` (the
    detectors in the order of the method's streams or the combination's detectors)."""


def _fixed_settings(settings: SweepSettings, label: str, kind: str) -> SweepSettings:
    """A grid that holds the single configuration ``(label, kind)`` (the sweep's deltas)."""
    cumulative = label == CUMULATIVE
    return SweepSettings(windows=(1,) if cumulative else (int(label),), cumulative=cumulative,
                         deltas=settings.deltas, kinds=(kind,), combines=settings.combines, pairs="diagonal",
                         max_pool=())


def sweep_task(
    streams: dict[str, StreamScores], methods: list[str], settings: SweepSettings, base: ThresholdSettings,
    thresholds: bool = False,
) -> TaskSweep:
    """Every configuration's first alarms ``[groups, deltas, test rollouts]`` of one task and seed (and with
    ``thresholds`` the thresholds they were decided with, :attr:`TaskSweep.thresholds`).

    ``base`` carries the profile's threshold rules and the seed of the CP band split.
    """
    groups: list[Group] = []
    alarms: list[np.ndarray] = []
    infinite: list[np.ndarray] = []
    conformal: list[int] = []
    gammas: list[np.ndarray] | None = [] if thresholds else None
    pairs = settings.fiper_pairs() if FIPER in methods else []
    kept: dict[str, dict[str, LabelAlarms]] = {s: {} for s in FIPER_STREAMS}
    # an OR at promise delta: FIPER's thresholds at the deltas its columns need (:meth:`SweepSettings.threshold_delta`)
    per_combine = {combine: replace(settings, deltas=tuple(settings.threshold_delta(d, combine, len(FIPER_STREAMS))
                                                           for d in settings.deltas)) for combine in settings.combines}
    halved = {combine: own for combine, own in per_combine.items() if own.deltas != settings.deltas}
    kept_at: dict[str, dict[str, dict[str, LabelAlarms]]] = {c: {s: {} for s in FIPER_STREAMS} for c in halved}
    for name, stream in streams.items():
        keep = {pair[FIPER_STREAMS.index(name)] for pair in pairs} if name in FIPER_STREAMS else set()
        fixed = METHODS[name].fixed if name in METHODS else None
        grid = settings if fixed is None else _fixed_settings(settings, *fixed)
        for combine, own in halved.items():
            if keep:
                kept_at[combine][name] = {r.label: r for r in _stream_alarms(stream, own, base, keep)
                                          if r.exceeded is not None}
        for result in _stream_alarms(stream, grid, base, keep):
            if result.exceeded is not None:
                kept[name][result.label] = result
            if name in methods and (fixed is None or result.label == fixed[0]):
                groups.extend(Group(name, result.label, kind) for kind in grid.kinds)
                alarms.extend(result.first)
                infinite.extend(result.infinite)
                conformal.extend(result.conformal.tolist())
                if gammas is not None:
                    gammas.extend(result.gamma[:, :, None, :])
    for obs_label, act_label in pairs:
        for combine in settings.combines:
            own = kept_at.get(combine, kept)
            obs, act = own["rnd_oe"][obs_label], own["ace"][act_label]
            assert obs.exceeded is not None and act.exceeded is not None
            fused = np.asarray(fuse(obs.exceeded, act.exceeded, combine), dtype=bool)
            groups.extend(Group(FIPER, f"{obs_label}/{act_label}", kind, combine) for kind in settings.kinds)
            alarms.extend(first_alarms(fused))
            infinite.extend(obs.infinite | act.infinite)
            conformal.extend(np.minimum(obs.conformal, act.conformal).tolist())
            if gammas is not None:
                gammas.extend(np.stack([obs.gamma, act.gamma], axis=2))  # per kind [deltas, 2, T]
    return TaskSweep(groups, np.stack(alarms), np.stack(infinite), np.array(conformal, dtype=int), gammas)
