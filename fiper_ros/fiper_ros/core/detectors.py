"""The detectors: their names, what each reads, and which sets a calibration declares.

FIPER fuses two detectors (eq. 7): RND-OE on the observation embeddings and ACE on the sampled action
chunks. A policy that publishes no action batches (or data recorded without them) can still be watched
by RND-OE alone: an *observation-only* calibration declares ``("rnd_oe",)``, and every part of the suite
(calibration, the nodes, replay, evaluation) then judges with RND-OE's exceedance alone. Only these two
sets are supported by the calibration file: ACE alone would need no RND-OE, which it always holds.

:data:`INFO` describes every per-step score stream the project computes (FIPER's two, the baselines, the
elapsed time, progress, action consistency), and :func:`info` also a user's logged signals (``signal_<name>``)
and a user's external scores (``external_<name>``, per-step scores of a detector computed elsewhere, read from a
file by ``fiper evaluate --scores``): what it reads, whether it learns from the successes, and where its
aggregation or normalisation is fixed by what it is.
"""
from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

from fiper_ros.core.errors import ChoiceError

RND_OE = "rnd_oe"
ACE = "ace"
#: What a detector reads at each policy step.
READS = ("embedding", "actions", "signal", "step", "external")
ELAPSED = "elapsed"
PROGRESS = "progress"
CONSISTENCY = "consistency"
LOGPZO = "logpzo"
PCA_KMEANS = "pca_kmeans"
#: Detectors a calibration may declare (besides the logged signals ``signal_<name>``), in the order the fusion
#: reports them: FIPER's pair first.
CALIBRATED = (RND_OE, ACE, LOGPZO, PCA_KMEANS, PROGRESS, CONSISTENCY, ELAPSED)
#: A logged per-step signal ``name`` is the stream ``signal_<name>``.
SIGNAL_PREFIX = "signal_"
#: A user's external per-step scores ``name`` are the stream ``external_<name>``.
EXTERNAL_PREFIX = "external_"
#: What a logged signal's (or external scores') name must be: it becomes part of ROS topic and stream names
#: (``signal_chunk_mse``).
SIGNAL_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class DetectorInfo:
    """What a per-step score stream is.

    Attributes:
        name: The stream's name (also its score topic's last part).
        label: Its name for people.
        reads: One of :data:`READS` (``"external"``: the scores are given, computed elsewhere).
        fitted: Whether it learns from the successes (a score model, a range, a centroid); an unfitted stream
            scores every rollout alike whatever the split. External scores count as unfitted: they are given per
            rollout, whatever the split; whether their model saw calibration rollouts is the user's to know.
        aggregation: Its aggregation when fixed by what it is (``None``: the configured window).
        shape: Its normalisation in a joint combination when fixed (``None``: the configured kind).
    """

    name: str
    label: str
    reads: str
    fitted: bool = True
    aggregation: str | None = None
    shape: str | None = None


#: Every built-in stream. The elapsed time scores 1 per step, so only its cumulative sum (the steps elapsed)
#: means anything, and its curves do not spread across successes at a step: its shape is CP scaled's per-step
#: quantile (a CP band's spread would be 0 there).
INFO: dict[str, DetectorInfo] = {d.name: d for d in (
    DetectorInfo(RND_OE, "RND-OE", "embedding"),
    DetectorInfo(ACE, "ACE", "actions"),
    DetectorInfo(LOGPZO, "logpZO", "embedding"),
    DetectorInfo(PCA_KMEANS, "PCA-kmeans", "embedding"),
    DetectorInfo("rnd_a", "RND-A", "actions"),
    DetectorInfo("stac", "STAC", "actions", fitted=False),
    DetectorInfo(PROGRESS, "progress", "embedding"),
    DetectorInfo(CONSISTENCY, "consistency", "actions"),
    DetectorInfo(ELAPSED, "elapsed time", "step", fitted=False, aggregation="cumulative", shape="cp_scaled"),
)}


def signal_stream(signal: str) -> str:
    """The stream of a logged per-step signal: ``signal_<signal>``; :class:`~fiper_ros.core.errors.ChoiceError` for
    a name that cannot be one."""
    if not SIGNAL_NAME.fullmatch(signal):
        raise ChoiceError(f"signal name {signal!r} must match [a-z][a-z0-9_]* (it becomes a topic and a stream name)")
    return SIGNAL_PREFIX + signal


def external_stream(name: str) -> str:
    """The stream of a user's external scores: ``external_<name>``; :class:`~fiper_ros.core.errors.ChoiceError` for a
    name that cannot be one."""
    if not SIGNAL_NAME.fullmatch(name):
        raise ChoiceError(f"external score name {name!r} must match [a-z][a-z0-9_]* (it becomes the stream "
                          f"{EXTERNAL_PREFIX}<name>)")
    return EXTERNAL_PREFIX + name


def info(name: str) -> DetectorInfo:
    """The :class:`DetectorInfo` of a stream name (``signal_<name>`` for a logged signal, ``external_<name>`` for
    external scores); :class:`~fiper_ros.core.errors.ChoiceError` naming the known ones otherwise."""
    if name in INFO:
        return INFO[name]
    for prefix, reads in ((SIGNAL_PREFIX, "signal"), (EXTERNAL_PREFIX, "external")):
        if name.startswith(prefix) and SIGNAL_NAME.fullmatch(name[len(prefix):]):
            return DetectorInfo(name, f"{reads} {name[len(prefix):]}", reads, fitted=False)
    raise ChoiceError(f"unknown detector {name!r}; expected one of {', '.join(INFO)}, signal_<name> or "
                      "external_<name>")


#: FIPER's detectors, in the order the fusion reports them (observation first).
DETECTORS: tuple[str, ...] = (RND_OE, ACE)
#: An observation-only calibration: RND-OE alone, no action batches needed.
OBSERVATION_ONLY: tuple[str, ...] = (RND_OE,)
#: The detector sets a calibration of format 2 could declare.
PAIR_FORMAT_SETS: tuple[tuple[str, ...], ...] = (DETECTORS, OBSERVATION_ONLY)
#: How a detector is named in messages to people.
LABELS = {name: detector.label for name, detector in INFO.items()}


def check_once(names: Iterable[str]) -> tuple[str, ...]:
    """``names`` as a declared set: each detector once, at least one; :class:`~fiper_ros.core.errors.ChoiceError`
    otherwise."""
    given = tuple(names)
    if not given or len(set(given)) != len(given):
        raise ChoiceError(f"declare each detector once, at least one, got {','.join(given) or '(none)'}")
    return given


def in_fusion_order(names: Iterable[str]) -> tuple[str, ...]:
    """``names`` in the fusion's order: the known detectors in :data:`INFO`'s order, then the others (logged
    signals) in the order given."""
    given = tuple(names)
    return tuple(d for d in INFO if d in given) + tuple(d for d in given if d not in INFO)


def check_pair_format(names: Iterable[str]) -> tuple[str, ...]:
    """``names`` as a detector set of a format-2 calibration, in :data:`DETECTORS` order;
    :class:`~fiper_ros.core.errors.ChoiceError` naming the sets otherwise."""
    given = tuple(names)
    ordered = tuple(d for d in DETECTORS if d in given)
    if sorted(given) != sorted(ordered) or ordered not in PAIR_FORMAT_SETS:
        supported = " or ".join(",".join(s) for s in PAIR_FORMAT_SETS)
        raise ChoiceError(f"unsupported detectors {','.join(given) or '(none)'}: declare {supported}")
    return ordered


def declarable(name: str) -> bool:
    """Whether a calibration can declare the stream ``name``: a calibrated detector or a logged signal (not an
    evaluation baseline nor external scores)."""
    return name in CALIBRATED or info(name).reads == "signal"


def check_declared(name: str) -> str:
    """``name`` if a calibration can declare it (:func:`declarable`); :class:`~fiper_ros.core.errors.ChoiceError`
    naming the detectors that can."""
    if declarable(name):
        return name
    raise ChoiceError(f"detector {name!r} cannot be calibrated (an evaluation baseline); declare some of "
                      f"{', '.join(CALIBRATED)} or signal_<name>")


def judged_by(detectors: Iterable[str], combine: str) -> str:
    """Which detectors judge and how their decisions combine, for people: ``"RND-OE and ACE"`` (FIPER's pair under
    ``and``, eq. 7), ``"RND-OE alone (observation-only: no ACE)"``, ``"RND-OE and ACE (max)"`` or ``"RND-OE, progress
    and elapsed time (kth:2)"``. ``combine`` is the calibration's (``""``: not known, e.g. no alarm seen yet; one
    detector alone ignores it)."""
    given = tuple(detectors)
    labels = [info(d).label for d in given]
    if given == OBSERVATION_ONLY:
        return f"{labels[0]} alone (observation-only: no {info(ACE).label})"
    if len(given) == 1:
        return f"{labels[0]} alone"
    if given == DETECTORS and combine == "and":
        return " and ".join(labels)
    how = combine or "combine not known"
    return f"{', '.join(labels[:-1])} and {labels[-1]} ({how})"
