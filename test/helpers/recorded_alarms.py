"""The alarm decisions a suite published, as a bag recorded them, in the offline oracle's terms (the live tests
compare them with :func:`fiper_ros.evaluation.offline.predict_bag` step for step)."""
from __future__ import annotations

from fiper_ros.bagio.reader import BagReader
from fiper_ros.evaluation.results import StepResult
from fiper_ros.interface.topics import ALARM_TOPIC


def alarm_steps(reader: BagReader, rollout_id: int) -> dict[int, StepResult]:
    """The recorded FailureAlarm decisions (not heartbeats) of ``rollout_id``, per step (a score of a detector
    that was not judged, NaN on the wire, is ``None`` as in the oracle)."""
    alarms = (reader.decode(m) for m in reader.messages([ALARM_TOPIC]))
    return {int(m.step): StepResult.of_alarm(m) for m in alarms if m.rollout_id == rollout_id and not m.heartbeat}
