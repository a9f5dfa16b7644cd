"""Which detectors a calibration declares: FIPER's pair, or RND-OE alone (issue #19).

FIPER fuses two detectors (eq. 7): RND-OE on the observation embeddings and ACE on the sampled action
chunks. A policy that publishes no action batches (or data recorded without them) can still be watched
by RND-OE alone: an *observation-only* calibration declares ``("rnd_oe",)``, and every part of the suite
(calibration, the nodes, replay, evaluation) then judges with RND-OE's exceedance alone. Only these two
sets are supported: ACE alone would need no RND-OE, which the calibration format always holds.
"""
from __future__ import annotations

from collections.abc import Iterable

RND_OE = "rnd_oe"
ACE = "ace"
#: FIPER's detectors, in the order the fusion reports them (observation first).
DETECTORS: tuple[str, ...] = (RND_OE, ACE)
#: An observation-only calibration: RND-OE alone, no action batches needed.
OBSERVATION_ONLY: tuple[str, ...] = (RND_OE,)
#: The detector sets a calibration may declare.
DETECTOR_SETS: tuple[tuple[str, ...], ...] = (DETECTORS, OBSERVATION_ONLY)
#: How a detector is named in messages to people.
LABELS = {RND_OE: "RND-OE", ACE: "ACE"}
#: A detector's side, as the calibration file (``thresholds.obs``, ``windows.act``) and FailureAlarm
#: (``eta_obs``, ``gamma_act``) name it.
SIDES = {RND_OE: "obs", ACE: "act"}


def check_detectors(names: Iterable[str]) -> tuple[str, ...]:
    """``names`` as a supported detector set in :data:`DETECTORS` order; ``ValueError`` naming the sets otherwise."""
    given = tuple(names)
    ordered = tuple(d for d in DETECTORS if d in given)
    if sorted(given) != sorted(ordered) or ordered not in DETECTOR_SETS:
        supported = " or ".join(",".join(s) for s in DETECTOR_SETS)
        raise ValueError(f"unsupported detectors {','.join(given) or '(none)'}: declare {supported}")
    return ordered


def judged_by(detectors: Iterable[str]) -> str:
    """Which detectors judge, for people: ``"RND-OE and ACE"``, or ``"RND-OE alone (observation-only: no ACE)"``."""
    given = tuple(detectors)
    absent = [LABELS[d] for d in DETECTORS if d not in given]
    named = " and ".join(LABELS[d] for d in given)
    return f"{named} alone (observation-only: no {', '.join(absent)})" if absent else named


def parse_detectors(text: str) -> tuple[str, ...]:
    """A comma-separated detector list (``"rnd_oe"``, ``"rnd_oe,ace"``) as a supported set."""
    return check_detectors(part.strip() for part in text.split(",") if part.strip())
