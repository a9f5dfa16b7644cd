"""The shipped Foxglove layout of the suite (``fiper_ros/config/foxglove/fiper.layout.json``), made from the
layout classes of the ``foxglove-sdk`` (``foxglove.layouts``).

One layout for the live view (``fiper view``) and for bags (``fiper record``, the demo's): it names the suite's
topics in the default namespace ``/fiper`` and the fields of its messages, which Foxglove reads alike from a
JSON channel of the view and from the CDR messages of a bag. Per detector a calibration may declare a plot of the
windowed score and its threshold (FIPER's pair side by side in the first tab, every other detector in a tab of its
own); the alarm state as state transitions (OK / ALARM / UNKNOWN named, with the rollout id); the latest
alarm's reason; both cameras; the nodes' diagnostics; and a note on what each panel shows.

Regenerate it after a change here (a test fails until then)::

    python -m fiper_ros.view.layout fiper_ros/config/foxglove/fiper.layout.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import foxglove.layouts as fl

from fiper_ros.core.detectors import ACE, CALIBRATED, LABELS, RND_OE
from fiper_ros.data_paths import package_share
from fiper_ros.interface.messages import AlarmStateName
from fiper_ros.interface.topics import (ALARM_TOPIC, CAMERA_THIRD_TOPIC, CAMERA_TOPICS, CAMERA_WRIST_TOPIC,
                                        DIAGNOSTICS_TOPIC, score_topic)

#: Where the layout is kept, relative to the ``fiper_ros`` package folder (installed in its share directory).
LAYOUT_FILE = Path("config") / "foxglove" / "fiper.layout.json"
#: The score topic of each detector a calibration may declare, FIPER's pair first.
SCORE_TOPICS = {detector: score_topic(detector) for detector in CALIBRATED}
#: The subscripts the paper gives FIPER's pair (``eta_O``, ``gamma_A``), written as the plots' labels do.
SUBSCRIPTS = {RND_OE: "obs", ACE: "act"}
#: The colour of each alarm state in the state-transitions panel (named there by its code's upper-case name).
STATE_COLOURS = {AlarmStateName.OK: "#2ca02c", AlarmStateName.ALARM: "#d62728", AlarmStateName.UNKNOWN: "#7f7f7f"}
CAMERA_TITLES = {CAMERA_WRIST_TOPIC: "wrist camera", CAMERA_THIRD_TOPIC: "third-person camera"}

ABOUT = """\
### What you see

**Scores** (one plot per detector): the windowed score (RND-OE on the policy's observation embeddings, eq. 2;
ACE on its sampled action chunks, eq. 5; in the other tabs each further detector a calibration may declare) and
the calibrated threshold of the same step. A score above its threshold *exceeds*. The alarm's combine says how
the exceedances count: *and* needs all, *or* and *max* one, *kth:K* K of them.

**Alarm**: the fused decision of every policy step on `/fiper/alarm`. OK: no failure predicted. ALARM: the
detectors exceed as the fusion rule asks (both, with `and`: eq. 7); it stays ALARM for the rest of the rollout.
UNKNOWN: no decision possible (a score stream missing, stale or uncalibrated): treat it like an alarm if it
lasts. The *reason* panel says why, e.g. *RND-OE 1.9x threshold since step 10, ACE 1.05x since step 25: both
exceeded (and)*.

**Cameras**: what the policy sees (the sim bridge's cameras; empty when none publishes).
**Diagnostics**: every node's health, one line each.

A detector the calibration does not declare has no scores: its plot stays empty (ACE's, for an observation-only
calibration). docs/view.md has the details.
"""


def _score_plot(detector: str) -> fl.PlotPanel:
    topic, label = SCORE_TOPICS[detector], LABELS[detector]
    side = SUBSCRIPTS.get(detector, detector)
    return fl.PlotPanel(title=f"{label}: windowed score and threshold", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"{topic}.windowed_score", label=f"{label} windowed score (eta_{side})",
                             color="#1f77b4", line_size=1.5),
               fl.PlotSeries(value=f"{topic}.threshold", label=f"threshold (gamma_{side})", color="#d62728",
                             line_style="dashed", line_interpolation="step")],
        show_legend=True, legend_display="top", is_synced=True, y_axis_label=f"{label} score"))


def _alarm_states() -> fl.StateTransitionsPanel:
    states = fl.StateTransitionsRangeCustomStates(states=[
        fl.StateTransitionsRangeCustomState(value=float(state.code), operator="=", label=state.name, color=color)
        for state, color in STATE_COLOURS.items()])
    return fl.StateTransitionsPanel(title="alarm state", config=fl.StateTransitionsConfig(
        paths=[fl.StateTransitionsSeries(value=f"{ALARM_TOPIC}.state", label="alarm", custom_states=states),
               fl.StateTransitionsSeries(value=f"{ALARM_TOPIC}.rollout_id", label="rollout")],
        is_synced=True, show_points=True))


def _column(*panels: fl.BasePanel | fl.TabContainer, sizes: tuple[float, ...]) -> fl.SplitContainer:
    return fl.SplitContainer(direction="column", items=[fl.SplitItem(proportion=size, content=panel)
                                                        for panel, size in zip(panels, sizes, strict=True)])


def build() -> fl.Layout:
    """The layout."""
    reason = fl.MarkdownPanel(title="why: the alarm's reason", config=fl.MarkdownConfig(
        render_mode="message", message_path=f"{ALARM_TOPIC}.reason"))
    cameras = [fl.ImagePanel(title=CAMERA_TITLES[topic], config=fl.ImageConfig(
        image_mode=fl.ImageModeConfig(image_topic=topic))) for topic in CAMERA_TOPICS]
    health = fl.TabContainer(tabs=[
        fl.TabItem(title="diagnostics", content=fl.DiagnosticsSummaryPanel(
            title="node health", config=fl.DiagnosticsSummaryConfig(topic_to_render=DIAGNOSTICS_TOPIC,
                                                                    sort_by_level=True))),
        fl.TabItem(title="what you see", content=fl.MarkdownPanel(title="what you see",
                                                                  config=fl.MarkdownConfig(markdown=ABOUT)))])
    pair = _column(_score_plot(RND_OE), _score_plot(ACE), sizes=(1, 1))
    scores = fl.TabContainer(tabs=[fl.TabItem(title=f"{LABELS[RND_OE]} and {LABELS[ACE]}", content=pair), *(
        fl.TabItem(title=LABELS[d], content=_score_plot(d)) for d in SCORE_TOPICS if d not in (RND_OE, ACE))])
    left = _column(scores, _alarm_states(), reason, sizes=(6, 2, 1))
    right = _column(*cameras, health, sizes=(2, 2, 3))
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[fl.SplitItem(proportion=3, content=left),
                                                                      fl.SplitItem(proportion=2, content=right)]))


def layout_json() -> str:
    """The layout file's text: the SDK's JSON, indented, keys in the SDK's order, one final newline."""
    return json.dumps(json.loads(build().to_json()), indent=2) + "\n"


def topics_of(layout: object) -> set[str]:
    """The topics a layout (its parsed JSON) refers to: every string that starts with ``/``, up to its first
    ``.`` (a message path ``/topic.field`` names ``/topic``; topic names have no dots)."""
    if isinstance(layout, dict):
        return set().union(*(topics_of(v) for v in layout.values())) if layout else set()
    if isinstance(layout, list):
        return set().union(*(topics_of(v) for v in layout)) if layout else set()
    return {layout.split(".")[0]} if isinstance(layout, str) and layout.startswith("/") else set()


def installed_layout() -> str:
    """Where the shipped layout is installed (the package's share directory), for the messages that name it."""
    share = package_share()
    return str(share / LAYOUT_FILE) if share is not None else f"fiper_ros/{LAYOUT_FILE} (in the repository)"


def main(argv: list[str] | None = None) -> int:
    """``python -m fiper_ros.view.layout OUT``: write the layout to OUT."""
    parser = argparse.ArgumentParser(prog="python -m fiper_ros.view.layout", description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help=f"where to write it (the shipped one: fiper_ros/{LAYOUT_FILE})")
    args = parser.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(layout_json())
    print(f"layout written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
