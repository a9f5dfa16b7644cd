"""``fiper doctor``: report whether the workspace environment is complete and DDS stays local."""
from __future__ import annotations

import argparse
import importlib
import os

#: module (or module:attribute that must exist) -> what it provides to the suite
REQUIRED = {
    "rclpy": "ROS 2 client library",
    "fiper_msgs.msg:FailureAlarm": "the suite's interfaces (colcon build)",
    "torch": "RND-OE and the policies",
    "numpy": "the FIPER core",
    "mujoco": "the simulated robot",
    "pinocchio": "forward kinematics for ACE",
    "rosbags": "bag recording and replay",
    "mcap": "MCAP files",
    "yaml": "calibration files",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``fiper doctor`` takes no options."""
    del parser


def run(args: argparse.Namespace) -> int:
    """Print one line per check; exit 1 if any check fails."""
    del args
    failures = 0
    for target, role in REQUIRED.items():
        module, _, attribute = target.partition(":")
        try:
            loaded = importlib.import_module(module)
            if attribute:
                getattr(loaded, attribute)
            print(f"ok    {module:16s} {role}")
        except (ImportError, AttributeError) as exc:
            failures += 1
            print(f"FAIL  {module:16s} {role}: {exc}")
    discovery = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "")
    domain = os.environ.get("ROS_DOMAIN_ID", "")
    local = discovery == "LOCALHOST"
    failures += 0 if local else 1
    print(f"{'ok   ' if local else 'FAIL '} ROS_AUTOMATIC_DISCOVERY_RANGE={discovery or '(unset)'} (must be LOCALHOST)")
    print(f"{'ok   ' if domain else 'FAIL '} ROS_DOMAIN_ID={domain or '(unset)'}")
    failures += 0 if domain else 1
    return 1 if failures else 0
