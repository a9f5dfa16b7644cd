"""The alarm states by their short names, as the tests compare fused states with them."""
from __future__ import annotations

from fiper_ros.interface.messages import AlarmStateName

OK, ALARM, UNKNOWN = AlarmStateName.OK, AlarmStateName.ALARM, AlarmStateName.UNKNOWN
