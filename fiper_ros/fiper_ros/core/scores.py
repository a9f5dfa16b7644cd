"""Per-step FIPER scores under a profile: ``s_RND`` (eq. 1) and ``s_ACE`` (eq. 4).

Calibration, the streaming monitors and the vectorised rollout prediction all compute their
per-step scores here, so a score is the same number wherever it is computed. A score that is NaN or
infinite can never be compared with a threshold (``nan > gamma`` is False, which would read as "below"):
it raises :class:`NonFiniteScore` here, the one place every score passes, and the step is not judged.
"""

from __future__ import annotations

import numpy as np

from fiper_ros.core.ace import step_entropies
from fiper_ros.core.errors import CoreError
from fiper_ros.core.kinematics import ActionProjection
from fiper_ros.core.profiles import Profile
from fiper_ros.core.rnd_oe import RNDOE
from fiper_ros.core.rollout import Rollout

JOINT_POSITIONS_KEY = "joint_positions"


class NonFiniteScore(CoreError):
    """A per-step score is NaN or infinite: that step cannot be judged, and is never reported OK."""


def finite(scores: np.ndarray, what: str) -> np.ndarray:
    """``scores`` unchanged if every entry is finite, else :class:`NonFiniteScore` naming the first bad index."""
    finite_entries = np.isfinite(scores)
    if not finite_entries.all():
        bad = np.flatnonzero(~finite_entries)
        first = np.unravel_index(int(bad[0]), np.shape(scores)) if np.ndim(scores) else ()
        where = f" at index {tuple(int(i) for i in first)}" if first else ""
        raise NonFiniteScore(f"{what} is {np.ravel(scores)[bad[0]]}{where} ({bad.size} non-finite)")
    return scores


def obs_score(rnd: RNDOE, embedding: np.ndarray, profile: Profile) -> float:
    """``s_RND(O_t)`` of one embedding ``[E]`` (numpy path) plus the profile's epsilon; finite or raises."""
    return float(finite(np.float64(rnd.score_one(embedding) + profile.score_epsilon), "RND-OE score"))


def obs_scores(rnd: RNDOE, embeddings: np.ndarray, profile: Profile) -> np.ndarray:
    """``s_RND`` of every step of ``[T, E]``, step by step with the same numpy path as :func:`obs_score`."""
    scores = np.empty(len(embeddings), dtype=np.float64)
    for t, embedding in enumerate(embeddings):
        try:
            scores[t] = obs_score(rnd, embedding, profile)
        except NonFiniteScore as error:
            raise NonFiniteScore(f"step {t}: {error}") from error
    return scores


def act_scores(positions: np.ndarray, cell: np.ndarray, profile: Profile) -> np.ndarray:
    """``s_ACE`` of position batches ``[..., B, H, P]`` -> ``[...]`` (sum or mean over ``H``, plus epsilon);
    finite or raises :class:`NonFiniteScore`."""
    entropies = step_entropies(positions, cell, profile.range_buffer, profile.ace_binning)
    reduced = entropies.sum(axis=-1) if profile.ace_reduce == "sum" else entropies.mean(axis=-1)
    return finite(reduced + profile.score_epsilon, "ACE score")


def act_score(positions: np.ndarray, cell: np.ndarray, profile: Profile) -> float:
    """``s_ACE`` of one position batch ``[B, H, P]``."""
    return float(act_scores(positions, cell, profile))


def step_joint_position(rollout: Rollout, step: int) -> np.ndarray | None:
    """The measured joint position at ``step`` (``metadata["joint_positions"]``), if recorded."""
    joints = rollout.metadata.get(JOINT_POSITIONS_KEY)
    return None if joints is None else np.asarray(joints[step], dtype=np.float64)


def rollout_positions(rollout: Rollout, projection: ActionProjection) -> np.ndarray:
    """ACE positions ``[T, B, H, P]`` of every action batch of a rollout."""
    if projection.action_space == "ee_position":
        return projection(rollout.actions.reshape(-1, *rollout.actions.shape[2:])).reshape(
            *rollout.actions.shape[:3], -1
        )
    return np.stack([projection(rollout.actions[t], step_joint_position(rollout, t)) for t in range(rollout.length)])
