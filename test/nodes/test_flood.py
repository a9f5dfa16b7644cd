"""A flood of malformed messages over DDS, interleaved with a valid recorded rollout (issue #18).

The suite runs as separate processes under ``fiper launch`` (the scoring nodes on the Pretzel sample
calibration, the fusion node, the example supervisor). The test's driver publishes a recorded failing Pretzel
rollout (``bags/pretzel_synthetic/test_rollouts``) step by step, and after each step's verdict a burst of
malformed messages of every kind the scoring and fusion nodes subscribe to: ObservationEmbedding and
ActionChunkBatch with NaN, 3e38, empty, oversize, lying shapes and sizes, other action spaces; RolloutEvent
ENDs and meaningless event codes of other rollouts, repeated STARTs of the valid one; Score of other rollouts
and of unknown detectors. Afterwards every process is alive (not restarted), each node counted every malformed
message as rejected, and the valid rollout's verdicts equal the offline oracle step for step (state, exceeded
flags, windowed scores and thresholds as float32).

What the malformed messages may not do is change the valid rollout's verdicts legitimately, so:

- inputs of the valid rollout id carry only steps its nodes must reject before they take them: a step it
  already had (duplicate, out of order), more than ``max_step_gap`` ahead, or at or beyond the START's
  ``max_steps``; they go out on the driver's own publishers right after the step's verdict, so DDS delivers them
  after the step they repeat. Malformed content (NaN, sizes) therefore travels under other rollout ids, which
  never started: the nodes hold them for their START and then reject them as ``unknown_rollout`` (content of an
  admitted step is rejected in ``test_bad_input.py`` and the fuzz tests);
- the fusion node's Score input gets only other rollout ids: a foreign publisher of Scores of the valid rollout
  could legitimately make the fusion node say UNKNOWN. The flood is a publisher the suite does not expect (issue
  #26: while one speaks on a score topic the fusion node never says OK), so the launch names it in the allow-lists
  (``score_publishers``, ``allowed_publishers``): the test is about malformed messages, not about who sends them.
  Before the rollout the fusion node's graph names the flood on each of its topics with nothing unexpected: a
  publisher the graph does not name yet counts beside the suite's (a second publisher, ``test_publishers.py``)
  and one unnamed for longer than its grace is a finding, so the suite's start-up and the flood's discovery may
  count findings that go again (a fresh-clone run under load counted 3: one per topic the flood publishes). The
  flood may add none;
- no START of another rollout (that would end the valid one) and no END of the valid one.

Bursts stay below the subscriptions' queue depths (inputs 100, scores 50, events 10), so that the flood does not
push a valid message out of a queue: that would be a legitimate loss, not a fault.
"""
from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from helpers.launch import Rig, open_rig, suite_config
from helpers.suite import STEP_NS, assert_as_the_oracle
from rclpy.node import Node

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, ObservationEmbedding, RolloutEvent, Score
from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.monitor import RolloutPrediction, predict_rollout
from fiper_ros.core.rollout import Rollout
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import action_batch_msg, embedding_msg, float_array, rollout_event_msg
from fiper_ros.nodes.graph_watch import PUBLISHERS_KEY
from fiper_ros.runtime.validation import DEFAULT_MAX_STEP_GAP

PRETZEL = Path(os.environ["FIPER_ROOT"]) / "bags" / "pretzel_synthetic"
#: A failing test rollout whose alarm comes mid-way (step 22 of 69): OK and ALARM verdicts both.
ROLLOUT = "17"
ROLLOUT_ID = 17
#: The largest accepted message: above the valid ones (a batch is 30 x 16 x 5 = 2400 values), so that oversize
#: messages stay cheap to send.
MAX_ELEMENTS = 4096
#: Rollout ids the flood uses (never started).
FOREIGN = 1_000_000
NODES = ("rnd_oe_node", "ace_node", "fusion_node", "supervisor_node")


@pytest.fixture(scope="module")
def pretzel() -> tuple[Rollout, RolloutPrediction]:
    rollout = next(r for r in read_rollouts(PRETZEL / "test_rollouts") if r.rollout_id == ROLLOUT)
    prediction = predict_rollout(rollout, load_calibration(PRETZEL / "calibration"))
    assert prediction.first_alarm_step is not None and 0 < prediction.first_alarm_step < rollout.length - 1
    return rollout, prediction


@pytest.fixture
def rig(tmp_path: Path, ros_domain: int) -> Iterator[Rig]:
    senders = ["test_driver", "flood"]  # the allow-lists: the test's driver and the flood (see the docstring)
    config = suite_config(tmp_path / "suite.yaml", PRETZEL / "calibration",
                          scoring={"max_elements": MAX_ELEMENTS, "allowed_publishers": senders},
                          fusion={"score_publishers": ["rnd_oe_node", "ace_node", "flood"],
                                  "allowed_publishers": senders})
    rig = open_rig(config, ros_domain)
    try:
        for name in NODES[:3]:
            rig.wait_healthy(name)
        yield rig
    finally:
        rig.close()


class Flood:
    """The malformed messages: inputs on the driver's own publishers (ordered after the valid steps), Scores and
    events on publishers of their own."""

    def __init__(self, rig: Rig, rollout: Rollout) -> None:
        self.driver = rig.driver
        self.rollout = rollout
        self.node = Node("flood", namespace="/fiper", context=rig.context)
        rig.executor.add_node(self.node)
        self.scores = {d: self.node.create_publisher(Score, f"scores/{d}", qos.SCORE_PUB) for d in ("rnd_oe", "ace")}
        self.events = self.node.create_publisher(RolloutEvent, "rollout_events", qos.EVENT)
        self.sent = {"embeddings": 0, "batches": 0, "scores": 0, "events": 0}
        self.rng = np.random.default_rng(18)
        assert rig.spin_until(lambda: all(p.get_subscription_count() >= 1 for p in self.scores.values())
                              and self.events.get_subscription_count() >= 4)

    def burst(self, t: int) -> None:
        """The malformed messages that follow the verdict of valid step ``t``."""
        for msg in self.embeddings(t):
            self.driver.embeddings.publish(msg)
            self.sent["embeddings"] += 1
        for msg in self.batches(t):
            self.driver.batches.publish(msg)
            self.sent["batches"] += 1
        for msg in self.foreign_scores(t):
            self.scores["ace" if msg.detector == "ace" else "rnd_oe"].publish(msg)
            self.sent["scores"] += 1
        for msg in self.bad_events(t):
            self.events.publish(msg)
            self.sent["events"] += 1

    def rejectable_steps(self, t: int) -> list[int]:
        """Steps of the valid rollout its nodes reject once they took step ``t``: again, behind, too far ahead,
        at and beyond max_steps."""
        length = self.rollout.length
        return [t, max(0, t - 1), t + DEFAULT_MAX_STEP_GAP + 2, 2**32 - 1, length, length + 1]

    def embeddings(self, t: int) -> list[ObservationEmbedding]:
        e = self.rollout.embeddings[t]
        foreign, stamp = FOREIGN + t % 7, (t + 1) * STEP_NS

        def emb(rollout_id: int, step: int, values: np.ndarray, shape: list[int] | None = None) -> ObservationEmbedding:
            msg = embedding_msg(rollout_id, step, stamp, values)
            if shape is not None:
                msg.shape = shape
            return msg

        nan = e.copy()
        nan[self.rng.integers(e.size)] = math.nan
        out = [emb(foreign, t, nan), emb(foreign, t, e, [e.size + 1]), emb(foreign, t, np.zeros(0, np.float32), []),
               emb(foreign, t, np.ones(MAX_ELEMENTS + 1, np.float32)), emb(foreign, t, np.full_like(e, 3e38)),
               emb(2**64 - 1, 2**32 - 1, e), emb(foreign, t, e[:16], [16, 3702849463, 793907557, 251])]
        out += [emb(ROLLOUT_ID, step, nan if step == t else e) for step in self.rejectable_steps(t)]
        return out

    def batches(self, t: int) -> list[ActionChunkBatch]:
        a, h = self.rollout.actions[t], self.rollout.exec_steps
        foreign, stamp = FOREIGN + t % 7, (t + 1) * STEP_NS

        def batch(rollout_id: int, step: int, values: np.ndarray, space: str = "ee_position",
                  exec_steps: int = h) -> ActionChunkBatch:
            return action_batch_msg(rollout_id, step, stamp, values, exec_steps, space)

        nan = a.copy()
        nan[0, 0, 0] = math.nan
        lying = batch(foreign, t, a)
        lying.batch_size = 2**32 - 1
        short = batch(foreign, t, a)
        short.data = float_array(a.ravel()[:-1])
        out = [batch(foreign, t, nan), lying, short, batch(foreign, t, a, "joint_velocity"),
               batch(foreign, t, a, exec_steps=0), batch(foreign, t, np.ones((2, 40, 60), np.float32)),
               batch(foreign, t, np.full_like(a, -3e38)), batch(2**64 - 1, 2**32 - 1, a)]
        out += [batch(ROLLOUT_ID, step, nan if step == t else a) for step in self.rejectable_steps(t)]
        return out

    def foreign_scores(self, t: int) -> list[Score]:
        out = []
        for n, (detector, value) in enumerate((("rnd_oe", 0.0), ("ace", math.nan), ("rnd_oe", math.inf),
                                               ("ace", 3e38), ("unknown", 1.0), ("", 0.5), ("rnd_oe", -1.0))):
            out.append(Score(rollout_id=FOREIGN + (t + n) % 11, step=t if n % 2 else 2**32 - 1 - t, detector=detector,
                             score=value, windowed_score=value, threshold=float(self.rng.uniform(0, 30)),
                             exceeded=bool(n % 3), complete=bool(n % 2), window=2**32 - 1))
        return out

    def bad_events(self, t: int) -> list[RolloutEvent]:
        out = [rollout_event_msg(FOREIGN + 20 + t, RolloutEvent.EVENT_END, 0, outcome=7),
               rollout_event_msg(FOREIGN + 40 + t, 7, 0, task="x" * 200, max_steps=2**32 - 1)]
        if t % 10 == 0:  # the valid rollout's START again: a repeat, which changes nothing
            out.append(rollout_event_msg(ROLLOUT_ID, RolloutEvent.EVENT_START, 0, max_steps=self.rollout.length))
        return out


#: The fusion node's inputs the flood publishes on.
FLOOD_TOPICS = ("/fiper/scores/rnd_oe", "/fiper/scores/ace", "/fiper/rollout_events")
FUSION = "fiper: /fiper/fusion_node"


def _publisher_values(rig: Rig) -> dict[str, str]:
    return {k: v for k, v in rig.driver.diagnostics.get(FUSION, {}).items() if "publisher" in k}


def _findings_once_the_flood_is_judged(rig: Rig) -> int:
    """Wait for a fusion report that names the flood's node on each of :data:`FLOOD_TOPICS` and finds nothing
    unexpected; the findings the node counted until then (the suite's start-up, the flood's discovery)."""
    rig.driver.diagnostics.pop(FUSION, None)

    def judged() -> bool:
        values = rig.driver.diagnostics.get(FUSION, {})
        return values.get("unexpected_publishers") == "0" and all(
            "/fiper/flood" in values.get(f"{PUBLISHERS_KEY}{topic}", "").split(",") for topic in FLOOD_TOPICS)

    assert rig.spin_until(judged, timeout=30), _publisher_values(rig)
    return int(rig.driver.diagnostics[FUSION]["unexpected_publishers_seen"])


def _rejected(rig: Rig, node: str) -> int:
    values = rig.driver.diagnostics.get(f"fiper: /fiper/{node}", {})
    return sum(int(v) for k, v in values.items() if k.startswith("rejected."))


@pytest.mark.slow
def test_a_flood_of_malformed_messages_changes_no_verdict_of_a_valid_rollout_and_kills_no_process(
        rig: Rig, pretzel: tuple[Rollout, RolloutPrediction]) -> None:
    rollout, prediction = pretzel
    driver, flood = rig.driver, Flood(rig, rollout)
    seen_before = _findings_once_the_flood_is_judged(rig)
    pids = {name: rig.launch.pids_of(name) for name in NODES}
    driver.events.publish(rollout_event_msg(ROLLOUT_ID, RolloutEvent.EVENT_START, 0, task="pretzel",
                                            max_steps=rollout.length))
    rig.pace(0.3)  # the nodes take the START before the first step
    for t in range(rollout.length):
        driver.step(ROLLOUT_ID, t, rollout.embeddings[t], rollout.actions[t], rollout.exec_steps)
        assert rig.spin_until(lambda s=t: s in driver.alarms_of(ROLLOUT_ID)), \
            (t, "\n".join(rig.launch.lines[-30:]))
        flood.burst(t)
    rig.pace(0.5)
    driver.end(ROLLOUT_ID, bool(rollout.success))
    sent = sum(flood.sent.values())
    assert sent >= 2000, flood.sent

    # every malformed input counted: the scoring nodes reject each (those of other rollouts once their START
    # wait ran out); the fusion node rejects each Score or still holds it for its START (at most 64)
    def counted() -> bool:
        fusion = driver.diagnostics.get("fiper: /fiper/fusion_node", {})
        return (_rejected(rig, "rnd_oe_node") == flood.sent["embeddings"]
                and _rejected(rig, "ace_node") == flood.sent["batches"]
                and _rejected(rig, "fusion_node") + int(fusion.get("waiting_for_start", -1)) == flood.sent["scores"])

    assert rig.spin_until(counted, timeout=30), (flood.sent, {n: driver.diagnostics.get(f"fiper: /fiper/{n}")
                                                              for n in NODES[:3]})
    for name, reasons in (("rnd_oe_node", ("duplicate_step", "out_of_order_step", "step_gap", "beyond_max_steps",
                                           "unknown_rollout")),
                          ("ace_node", ("duplicate_step", "out_of_order_step", "step_gap", "beyond_max_steps",
                                        "unknown_rollout")),
                          ("fusion_node", ("unknown_detector", "unknown_rollout"))):
        values = driver.diagnostics[f"fiper: /fiper/{name}"]
        assert all(int(values.get(f"rejected.{r}", 0)) > 0 for r in reasons), (name, values)
        assert values["lifecycle_state"] == "active", (name, values)
    # the allow-lists took: the fusion node found no publisher it does not expect, the flood included, and none
    # appeared while the flood ran
    fusion = driver.diagnostics[FUSION]
    assert (fusion["unexpected_publishers"], fusion["unexpected_publishers_seen"]) == ("0", str(seen_before)), \
        _publisher_values(rig)
    assert "/fiper/flood" in driver.diagnostics["fiper: /fiper/fusion_node"]["publishers./fiper/scores/ace"]

    # every process alive, none restarted, no traceback
    assert rig.launch.proc.poll() is None
    for name in NODES:
        assert rig.launch.pids_of(name) == pids[name], (name, "\n".join(rig.launch.lines[-30:]))
        os.kill(pids[name][-1], 0)  # raises if the process is gone
    assert not any("Traceback" in line for line in rig.launch.lines), "\n".join(rig.launch.lines)

    # the valid rollout judged exactly as offline: one verdict per step
    verdicts = [m for m in driver.alarms if m.rollout_id == ROLLOUT_ID and not m.heartbeat]
    assert sorted(m.step for m in verdicts) == list(range(rollout.length))
    assert_as_the_oracle(driver.alarms_of(ROLLOUT_ID), prediction)
    assert any(m.state == FailureAlarm.STATE_OK for m in verdicts) and any(
        m.state == FailureAlarm.STATE_ALARM for m in verdicts)
