"""What the message codes mean: alarm states, rollout outcomes, and message classes by type name.

The codes are those of the ``fiper_msgs`` definitions (``FailureAlarm.STATE_*``, ``RolloutEvent.OUTCOME_*``);
this module names them once for every node, bag tool and client.
"""
from __future__ import annotations

import importlib
from enum import StrEnum
from typing import Any

from fiper_msgs.msg import RolloutEvent

__all__ = ["NO_ROLLOUT", "OUTCOMES", "OUTCOME_NAMES", "OUTCOME_OF", "SUCCESS_OF", "AlarmStateName", "message_class",
           "outcome_name"]


class AlarmStateName(StrEnum):
    """The fused alarm state (paper eq. 7 decides between OK and ALARM; UNKNOWN: no decision possible), as the
    fusion logic, the supervisor and the results of a replay name it: the value is the lower-case name a result
    file holds, :attr:`name` the upper-case one a person reads, :attr:`code` the ``FailureAlarm.state`` code
    (``FailureAlarm.STATE_*``: ``test/msgs/test_messages.py`` checks that they agree)."""

    code: int

    def __new__(cls, value: str, code: int) -> AlarmStateName:
        member = str.__new__(cls, value)
        member._value_, member.code = value, code
        return member

    OK = "ok", 0
    ALARM = "alarm", 1
    UNKNOWN = "unknown", 2

    @classmethod
    def of_code(cls, code: int) -> AlarmStateName:
        """The state of a ``FailureAlarm.state`` code (:attr:`UNKNOWN` for a code this suite does not know)."""
        return next((state for state in cls if state.code == code), cls.UNKNOWN)


#: Rollout id of a state about no rollout (the fusion node is idle); the suite's rollout ids are > 0.
NO_ROLLOUT = 0
#: ``RolloutEvent.outcome`` -> outcome name.
OUTCOMES = {RolloutEvent.OUTCOME_UNKNOWN: "unknown", RolloutEvent.OUTCOME_SUCCESS: "success",
            RolloutEvent.OUTCOME_FAILURE: "failure"}
#: Rollout success (``Rollout.success``) -> ``RolloutEvent.outcome``, and back.
OUTCOME_OF = {True: RolloutEvent.OUTCOME_SUCCESS, False: RolloutEvent.OUTCOME_FAILURE,
              None: RolloutEvent.OUTCOME_UNKNOWN}
SUCCESS_OF = {v: k for k, v in OUTCOME_OF.items()}
#: Rollout success (``Rollout.success``) -> outcome name.
OUTCOME_NAMES = {success: OUTCOMES[code] for success, code in OUTCOME_OF.items()}


def outcome_name(outcome: int) -> str:
    """The name of a ``RolloutEvent.outcome`` code (``"unknown"`` for a code this suite does not know)."""
    return OUTCOMES.get(outcome, "unknown")


def message_class(type_name: str) -> Any:
    """The message class of ``pkg/msg/Name``."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)
