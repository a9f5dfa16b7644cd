"""Every OOD scenario really changes the scene (model parameters or pixels), deterministically."""
from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.env import make_env
from sim_bridge.scenarios import SCENARIOS, TASK_NAMES, get_scenario, knob_values
from sim_bridge.tasks import TaskEnv

CASES = [(task, name) for task in TASK_NAMES for name in SCENARIOS[task] if name != "id"]


def _fingerprint(env: TaskEnv) -> dict[str, np.ndarray]:
    m = env.model
    return {
        "geom_size": m.geom_size.copy(), "geom_pos": m.geom_pos.copy(), "geom_friction": m.geom_friction.copy(),
        "body_mass": m.body_mass.copy(), "light": np.concatenate([m.light_diffuse.ravel(), m.light_dir.ravel()]),
        "cam_pos": m.cam_pos.copy(),
    }


@pytest.mark.parametrize(("task", "name"), CASES)
def test_knobs_change_the_scene(task: str, name: str) -> None:
    scenario = get_scenario(task, name)
    assert scenario.kind in ("benign", "harmful")
    with make_env(task, "id", 5) as ref, make_env(task, name, 5) as ood:
        ref_obs, ood_obs = ref.reset(), ood.reset()
        ref_fp, ood_fp = _fingerprint(ref), _fingerprint(ood)
        changed = [k for k in ref_fp if ref_fp[k].shape != ood_fp[k].shape or not np.allclose(ref_fp[k], ood_fp[k])]
        assert changed, f"{task}/{name} changed no model parameter"
        visual_knobs = {"light_scale", "light_azimuth", "camera_shift", "block_scale", "box_shift", "target_shift",
                        "t_scale", "stem_scale", "bar_scale"}
        if visual_knobs & set(scenario.knobs):
            assert not np.array_equal(ref_obs["third_rgb"], ood_obs["third_rgb"])


def test_knob_values_are_seeded() -> None:
    scenario = get_scenario("pusht", "t_scale")
    assert knob_values(scenario, 3) == knob_values(scenario, 3)
    assert knob_values(scenario, 3)["t_scale"] != knob_values(scenario, 4)["t_scale"]
    low, high = scenario.knobs["t_scale"]
    assert low <= knob_values(scenario, 3)["t_scale"] <= high


def test_every_task_has_id_benign_and_harmful() -> None:
    for task in TASK_NAMES:
        kinds = {s.kind for s in SCENARIOS[task].values()}
        assert kinds == {"id", "benign", "harmful"}
