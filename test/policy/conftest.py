"""Fixtures of the policy tests: headless rendering, one torch thread, a synthetic demonstration folder."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from helpers.policy_fixtures import tiny_config, write_demos

os.environ.setdefault("MUJOCO_GL", "egl")
torch.set_num_threads(1)


@pytest.fixture
def demo_dir(tmp_path: Path) -> Path:
    """Three synthetic Sorting-format episodes."""
    return write_demos(tmp_path / "demos", tiny_config())
