"""What the message codes mean: alarm states, rollout outcomes, and message classes by type name.

The codes are those of the ``fiper_msgs`` definitions (``FailureAlarm.STATE_*``, ``RolloutEvent.OUTCOME_*``);
this module names them once for every node, bag tool and client.
"""
from __future__ import annotations

import importlib
from typing import Any

from fiper_msgs.msg import FailureAlarm, RolloutEvent

__all__ = ["ALARM", "NO_ROLLOUT", "OK", "OUTCOMES", "OUTCOME_NAMES", "OUTCOME_OF", "STATE_NAMES", "SUCCESS_OF",
           "UNKNOWN", "message_class", "outcome_name", "state_name"]

#: Alarm states, as the fusion logic, the results of a replay and the supervisor name them.
OK = "ok"
ALARM = "alarm"
UNKNOWN = "unknown"
#: Rollout id of a state about no rollout (the fusion node is idle); the suite's rollout ids are > 0.
NO_ROLLOUT = 0
#: ``FailureAlarm.state`` -> state name.
STATE_NAMES = {FailureAlarm.STATE_OK: OK, FailureAlarm.STATE_ALARM: ALARM, FailureAlarm.STATE_UNKNOWN: UNKNOWN}
#: ``RolloutEvent.outcome`` -> outcome name.
OUTCOMES = {RolloutEvent.OUTCOME_UNKNOWN: "unknown", RolloutEvent.OUTCOME_SUCCESS: "success",
            RolloutEvent.OUTCOME_FAILURE: "failure"}
#: Rollout success (``Rollout.success``) -> ``RolloutEvent.outcome``, and back.
OUTCOME_OF = {True: RolloutEvent.OUTCOME_SUCCESS, False: RolloutEvent.OUTCOME_FAILURE,
              None: RolloutEvent.OUTCOME_UNKNOWN}
SUCCESS_OF = {v: k for k, v in OUTCOME_OF.items()}
#: Rollout success (``Rollout.success``) -> outcome name.
OUTCOME_NAMES = {success: OUTCOMES[code] for success, code in OUTCOME_OF.items()}


def state_name(state: int) -> str:
    """The name of a ``FailureAlarm.state`` code (:data:`UNKNOWN` for a code this suite does not know)."""
    return STATE_NAMES.get(state, UNKNOWN)


def outcome_name(outcome: int) -> str:
    """The name of a ``RolloutEvent.outcome`` code (``"unknown"`` for a code this suite does not know)."""
    return OUTCOMES.get(outcome, "unknown")


def message_class(type_name: str) -> Any:
    """The message class of ``pkg/msg/Name``."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)
