"""Scenario registry: named, seeded variations of each task with their intended effect on a policy.

A scenario fixes which knobs deviate from the in-distribution (ID) defaults and the range each knob is
drawn from. ``(task, scenario name, seed)`` fully determines an episode: the object layout comes from
``layout_rng(seed)`` (so an OOD scenario reuses the ID layout of the same seed wherever its knobs allow)
and the knob values from ``knob_rng(scenario, seed)``.

``kind`` is the *intended* effect on a policy trained on ID demonstrations: ``"benign"`` (it should
still succeed) or ``"harmful"`` (it should fail more often); the ID scenario has kind ``"id"``. The
measured failure rates are a separate, later result.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from fiper_ros.errors import FiperError

from .scene import SceneParams

Kind = Literal["id", "benign", "harmful"]
TASK_NAMES: tuple[str, ...] = ("sorting", "stacking", "pusht")

COMMON_DEFAULTS: dict[str, float] = {
    "friction": 0.5,
    "mass_scale": 1.0,
    "light_scale": 1.0,
    "light_azimuth": 0.0,
    "camera_shift": 0.0,
}
"""ID values of the knobs every task understands (see ``scene_params``)."""

TASK_DEFAULTS: dict[str, dict[str, float]] = {
    "sorting": {"block_scale": 1.0, "box_shift": 0.0},
    "stacking": {"block_scale": 1.0, "target_shift": 0.0},
    "pusht": {"t_scale": 1.0, "stem_scale": 1.0, "bar_scale": 1.0},
}
"""ID values of the task-specific knobs (interpreted by each task module)."""


@dataclass(frozen=True)
class Scenario:
    """One named variation of a task.

    Attributes:
        name: Registry key, unique per task.
        task: Task name (one of ``TASK_NAMES``).
        kind: Intended effect on an ID-trained policy: ``"id"``, ``"benign"`` or ``"harmful"``.
        description: One line for documentation and dataset metadata.
        knobs: Knob name -> (low, high) range drawn uniformly per seed; unlisted knobs keep ID values.
    """

    name: str
    task: str
    kind: Kind
    description: str
    knobs: dict[str, tuple[float, float]] = field(default_factory=dict)


def _common(task: str) -> list[Scenario]:
    """Scenarios of the scene-level knobs shared by all tasks."""
    return [
        Scenario("id", task, "id", "in-distribution: the demonstrations' distribution"),
        Scenario("lighting", task, "benign", "dimmer main light from a side direction",
                 {"light_scale": (0.75, 0.9), "light_azimuth": (0.3, 0.6)}),
        Scenario("camera_shift", task, "benign", "third-person camera moved by 1.5-2.5 cm",
                 {"camera_shift": (0.015, 0.025)}),
        Scenario("camera_moved", task, "harmful", "third-person camera moved by 25-30 cm",
                 {"camera_shift": (0.25, 0.30)}),
        Scenario("mass_heavy", task, "benign", "objects 2-3x heavier", {"mass_scale": (2.0, 3.0)}),
    ]


SCENARIOS: dict[str, dict[str, Scenario]] = {
    task: {s.name: s for s in scenarios}
    for task, scenarios in {
        "sorting": _common("sorting") + [
            Scenario("block_size", "sorting", "harmful", "block footprint 1.5-1.7x wider (same height)",
                     {"block_scale": (1.5, 1.7)}),
            Scenario("box_pos", "sorting", "harmful", "both boxes 22-28 cm closer to the robot",
                     {"box_shift": (0.22, 0.28)}),
            Scenario("friction_low", "sorting", "harmful", "slippery table and blocks (mu 0.01-0.02)",
                     {"friction": (0.01, 0.02)}),
        ],
        "stacking": _common("stacking") + [
            Scenario("block_size", "stacking", "harmful", "blocks 1.45-1.6x larger", {"block_scale": (1.45, 1.6)}),
            Scenario("target_pos", "stacking", "harmful", "target area moved 62-70 cm to the robot's other side",
                     {"target_shift": (0.62, 0.70)}),
            Scenario("slippery_heavy", "stacking", "harmful", "mu 0.06-0.08 and blocks 3.5-5x heavier: grasps slip",
                     {"friction": (0.06, 0.08), "mass_scale": (3.5, 5.0)}),
        ],
        "pusht": _common("pusht") + [
            Scenario("t_scale", "pusht", "harmful", "T scaled 1.45-1.55x", {"t_scale": (1.45, 1.55)}),
            Scenario("t_shape", "pusht", "harmful",
                     "T stem 1.4-1.6x and bar 1.3-1.5x longer (it can still cover the goal)",
                     {"stem_scale": (1.4, 1.6), "bar_scale": (1.3, 1.5)}),
            Scenario("friction_high", "pusht", "benign", "rougher table and T (mu 0.7-0.8)",
                     {"friction": (0.7, 0.8)}),
        ],
    }.items()
}
"""Task -> scenario name -> Scenario."""


class ScenarioError(FiperError):
    """A task or scenario the simulator does not have (a flag, a node parameter or a reset request names it)."""


def get_scenario(task: str, name: str) -> Scenario:
    """Look up a scenario; :class:`ScenarioError` naming the valid names if unknown."""
    if task not in SCENARIOS:
        raise ScenarioError(f"unknown task {task!r}; tasks: {sorted(SCENARIOS)}")
    if name not in SCENARIOS[task]:
        raise ScenarioError(f"unknown scenario {name!r} for {task}; scenarios: {sorted(SCENARIOS[task])}")
    return SCENARIOS[task][name]


def layout_rng(seed: int) -> np.random.Generator:
    """Random stream of the object layout; depends on the seed only."""
    return np.random.default_rng(seed)


def knob_rng(scenario: Scenario, seed: int) -> np.random.Generator:
    """Random stream of the knob values; depends on task, scenario name and seed."""
    return np.random.default_rng([seed, zlib.crc32(f"{scenario.task}/{scenario.name}".encode())])


def knob_values(scenario: Scenario, seed: int) -> dict[str, float]:
    """Return every knob's value for this episode (ID defaults overridden by the scenario's draws)."""
    values = dict(COMMON_DEFAULTS) | TASK_DEFAULTS[scenario.task]
    rng = knob_rng(scenario, seed)
    for knob, (low, high) in sorted(scenario.knobs.items()):
        if knob not in values:
            raise KeyError(f"scenario {scenario.name!r} sets unknown knob {knob!r}")
        values[knob] = float(rng.uniform(low, high))
    # The camera shift direction is drawn even when the magnitude is zero to keep streams aligned.
    direction = rng.normal(size=3)
    values["camera_dx"], values["camera_dy"], values["camera_dz"] = (
        values["camera_shift"] * direction / np.linalg.norm(direction)
    )
    return values


def scene_params(values: dict[str, float]) -> SceneParams:
    """Scene-level parameters from knob values."""
    return SceneParams(
        friction=values["friction"],
        light_scale=values["light_scale"],
        light_azimuth=values["light_azimuth"],
        camera_offset=(values["camera_dx"], values["camera_dy"], values["camera_dz"]),
    )
