"""Shared settings of the simulation tests: headless EGL rendering and the sim_bridge import path."""
from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "sim_bridge"))
