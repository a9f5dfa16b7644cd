"""Issue #24: the scoring, fusion and supervisor nodes run without torch and mujoco, and a calibration of format 1
(RND-OE's weights in the torch file ``rnd_oe.pt``) is refused with the command that converts it.

Each check runs in a child interpreter whose first meta-path finder refuses ``torch`` and ``mujoco`` (and
records every attempt, so an ``import torch`` inside ``try`` counts too).

``test/data/calibration_format1`` was written by the code before this change (commit 1bb7237, in a worktree of
its own): ``calibrate`` on the rollouts ``make_rollout(np.random.default_rng(7), i)``, ``i < 24``, of
``helpers.core_data``, RND-OE ``RNDConfig(trunk=(16,), head=(16,), out_dim=8, max_epochs=20, lr=1e-3)``,
windows 3, ``cp_band`` at delta 0.2, then ``save``. ``test/data/calibration_format1_scores.json`` holds what
that code computed with it: the RND-OE score of every step and the alarmed steps of
``make_rollout(np.random.default_rng(8), 0)`` and ``make_rollout(rng, 1, ood=True)``, and its content hash.
It computed them on a CPU without AVX-512; where OpenBLAS picks other float32 kernels (AVX-512: its SkylakeX
ones, this machine since 2026-12-02) a matrix product rounds differently in its last bit or two, so a score of
the same weights and input may differ by a few float32 ulps from one CPU to another (on one machine it is the
same number wherever it is computed). The converted calibration's scores are compared to 1e-6 relative (about
8 ulps; measured: at most 2), its alarms exactly.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from helpers.core_data import make_rollout

from fiper_ros.core.calibration import CalibrationError, load_calibration, upgrade_calibration
from fiper_ros.core.calibration_file import upgrade_command
from fiper_ros.core.monitor import predict_rollout
from fiper_ros.core.scores import obs_scores
from fiper_ros.platform.dds import local_env

ROOT = Path(__file__).resolve().parents[2]
FORMAT1 = ROOT / "test" / "data" / "calibration_format1"
FORMAT1_SCORES = ROOT / "test" / "data" / "calibration_format1_scores.json"
SHIPPED = sorted([*ROOT.glob("models/*/calibration*"), *ROOT.glob("bags/*/calibration")])
#: For the joint-space calibration (Stacking): the ACE node's forward kinematics (pinocchio, which may be imported).
URDF = ROOT / "sim_bridge" / "sim_bridge" / "assets" / "panda" / "urdf" / "panda.urdf"

#: Prepended to every child's code: the import hook refusing torch and mujoco.
BLOCK = """
import importlib.abc, sys
REFUSED = []
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "mujoco"):
            REFUSED.append(name)
            raise ModuleNotFoundError(f"{name} is blocked by the test", name=name)
        return None
sys.meta_path.insert(0, Refuse())
"""
#: Appended: nothing tried to import them.
CHECK = """
assert not REFUSED, f"tried to import {REFUSED}"
assert not {"torch", "mujoco"} & set(sys.modules)
print("ok")
"""


def run_blocked(code: str, env: dict[str, str] | None = None) -> str:
    """Run ``code`` in a child interpreter with torch and mujoco refused; its stdout (asserts it succeeded)."""
    program = BLOCK + textwrap.dedent(code) + CHECK
    result = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=300, check=False,
                            env=env)
    assert result.returncode == 0 and result.stdout.endswith("ok\n"), result.stdout + result.stderr
    return result.stdout


def test_the_hook_refuses_torch() -> None:
    """The hook works: importing torch with it fails, and the check notices an attempt caught by the caller."""
    result = subprocess.run([sys.executable, "-c", BLOCK + "try:\n    import torch\nexcept ImportError:\n    pass\n"
                             + CHECK], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode != 0 and "tried to import ['torch']" in result.stderr


def test_the_nodes_reach_active_on_the_shipped_calibrations_without_torch_or_mujoco(ros_domain: int) -> None:
    """The node modules import, and each scoring node and the fusion node configure (load the calibration) and
    activate on every shipped calibration, and score an embedding with it."""
    run_blocked(f"""
        import numpy as np
        import rclpy
        from rclpy.lifecycle import TransitionCallbackReturn
        from rclpy.parameter import Parameter
        from fiper_ros.core.calibration import load_calibration
        from fiper_ros.nodes.ace_node import AceNode
        from fiper_ros.nodes.fusion_node import FusionNode
        from fiper_ros.nodes.rnd_oe_node import RndOeNode
        from fiper_ros.nodes.supervisor_node import SupervisorNode

        rclpy.init()
        supervisor = SupervisorNode(namespace="/fiper", start_parameter_services=False)
        for directory in {[str(d) for d in SHIPPED]!r}:
            params = [Parameter("autostart", value=False), Parameter("calibration_dir", value=directory),
                      Parameter("urdf_path", value={str(URDF)!r})]
            for cls in (RndOeNode, AceNode, FusionNode):
                node = cls(namespace="/fiper", parameter_overrides=params, start_parameter_services=False)
                assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS, (directory, node.config_error)
                node.trigger_activate()
                assert node.lifecycle_state() == "active", (directory, cls.__name__)
                node.destroy_node()
            calibration = load_calibration(directory)
            zeros = np.zeros(calibration.layout.embedding_dim, np.float32)
            assert np.isfinite(calibration.scorer("rnd_oe").rnd.score_one(zeros))
        supervisor.destroy_node()
        rclpy.shutdown()
        """, env=local_env(ros_domain))


def test_a_format1_calibration_is_refused_with_the_command_that_converts_it() -> None:
    """Without torch too: the refusal needs none."""
    expected = (f"{FORMAT1 / 'calibration.yaml'}: format_version 1, whose RND-OE weights (rnd_oe.pt) only torch "
                f"reads: convert it once with: {upgrade_command(FORMAT1)}")
    assert expected.endswith(f"fiper calibrate --upgrade {FORMAT1} -o {FORMAT1} --force")
    with pytest.raises(CalibrationError) as error:
        load_calibration(FORMAT1)
    assert str(error.value) == expected
    run_blocked(f"""
        from fiper_ros.core.calibration import CalibrationError, load_calibration
        try:
            load_calibration({str(FORMAT1)!r})
        except CalibrationError as error:
            assert str(error) == {expected!r}, str(error)
        else:
            raise AssertionError("a format-1 calibration loaded")
        """)


def test_the_converted_calibration_scores_and_alarms_as_the_old_code_did(tmp_path: Path) -> None:
    """``fiper calibrate --upgrade DIR -o DIR --force`` in place: the old content hash is checked on the way,
    and the converted calibration (loaded without torch) gives the old code's scores to float32 rounding (the
    module's doc) and its alarms exactly."""
    directory = tmp_path / "calibration"
    shutil.copytree(FORMAT1, directory)
    old = json.loads(FORMAT1_SCORES.read_text())
    assert upgrade_calibration(directory).threshold("rnd_oe").kind == "cp_band"
    result = subprocess.run([sys.executable, "-m", "fiper_ros.cli", *upgrade_command(directory).split()[1:]],
                            capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in directory.iterdir()) == ["calibration.yaml", "rnd_oe.json", "rnd_oe.npz"]
    converted = load_calibration(directory)
    assert converted.content_hash != old["content_hash"]  # the format version is part of the content
    rng = np.random.default_rng(8)
    for rollout in (make_rollout(rng, 0), make_rollout(rng, 1, ood=True)):
        expected = old["rollouts"][rollout.rollout_id]
        np.testing.assert_allclose(obs_scores(converted.scorer("rnd_oe").rnd, rollout.embeddings, converted.profile),
                                   expected["rnd_oe_scores"], rtol=1e-6, atol=0)
        assert np.flatnonzero(predict_rollout(rollout, converted).alarms).tolist() == expected["alarms"]
    run_blocked(f"""
        from fiper_ros.core.calibration import load_calibration
        assert load_calibration({str(directory)!r}).content_hash == {converted.content_hash!r}
        """)


def test_a_modified_format1_calibration_is_not_converted(tmp_path: Path) -> None:
    """The conversion checks the old content hash: an edited threshold is refused, not carried over."""
    directory = tmp_path / "calibration"
    shutil.copytree(FORMAT1, directory)
    path = directory / "calibration.yaml"
    path.write_text(path.read_text().replace("delta: 0.2", "delta: 0.3", 1))
    with pytest.raises(CalibrationError, match="content hash mismatch"):
        upgrade_calibration(directory)


def test_a_current_calibration_needs_no_conversion() -> None:
    with pytest.raises(CalibrationError, match="already of format_version 3, nothing to convert"):
        upgrade_calibration(SHIPPED[0])
