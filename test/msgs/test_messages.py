"""The names of ``interface/messages.py`` and ``core/fusion.py`` against the ``fiper_msgs`` constants they stand for."""
from __future__ import annotations

from fiper_msgs.msg import FailureAlarm
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.interface.messages import AlarmStateName


def test_state_codes_are_the_message_constants() -> None:
    assert {state.name: state.code for state in AlarmStateName} == {
        "OK": FailureAlarm.STATE_OK, "ALARM": FailureAlarm.STATE_ALARM, "UNKNOWN": FailureAlarm.STATE_UNKNOWN}


def test_a_state_is_named_by_its_code_and_an_unknown_code_is_unknown() -> None:
    assert [AlarmStateName.of_code(state.code) for state in AlarmStateName] == list(AlarmStateName)
    assert AlarmStateName.of_code(200) is AlarmStateName.UNKNOWN


def test_the_value_is_the_name_a_result_file_holds() -> None:
    assert [str(state) for state in AlarmStateName] == ["ok", "alarm", "unknown"]
    assert [state.name for state in AlarmStateName] == ["OK", "ALARM", "UNKNOWN"]


def test_the_message_names_the_combine_modes_as_the_core_does() -> None:
    assert (FailureAlarm.COMBINE_AND, FailureAlarm.COMBINE_OR, FailureAlarm.COMBINE_MAX) == \
        (CombineMode.AND, CombineMode.OR, CombineMode.MAX)
