"""One policy step's two detector scores through an AlarmFuser, by hand (test/runtime)."""
from __future__ import annotations

from fiper_ros.runtime.alarm import AlarmFuser, AlarmState, DetectorScore


def fuse_pair(fuser: AlarmFuser, step: int, obs: float, act: float, now: int = 0, *, rollout: int = 1,
              gamma: float | tuple[float, float] = 1.0, stamps: tuple[int, int] | None = None,
              complete: tuple[bool, bool] = (True, True), scored: tuple[bool, bool] = (True, True),
              flags: tuple[bool, bool] | None = None) -> AlarmState:
    """RND-OE's score of ``step`` (no state yet), then ACE's: the fused state. ``gamma``: both thresholds or
    each; ``stamps``: the scores' stamps (default ``now``); ``flags``: their exceeded flags (default: the true
    comparison)."""
    gamma_obs, gamma_act = gamma if isinstance(gamma, tuple) else (gamma, gamma)
    stamp_obs, stamp_act = stamps if stamps is not None else (now, now)
    obs_flag, act_flag = flags if flags is not None else (obs > gamma_obs, act > gamma_act)
    first = fuser.add(DetectorScore("rnd_oe", rollout, step, obs, gamma_obs, stamp_obs, complete[0], obs_flag,
                                    scored[0]), now)
    assert first is None
    state = fuser.add(DetectorScore("ace", rollout, step, act, gamma_act, stamp_act, complete[1], act_flag, scored[1]),
                      now)
    assert state is not None
    return state
