"""``fiper launch CONFIG.yaml``: start the suite's nodes from a launch YAML (:mod:`fiper_ros.launcher`)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from fiper_ros.dds import die_with_parent
from fiper_ros.launcher.config import LaunchError, load_config
from fiper_ros.launcher.processes import run_in_process, run_processes
from fiper_ros.shm import clean_stale


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper launch``."""
    parser.add_argument("config", type=Path, help="launch YAML, e.g. fiper_ros/config/suite.yaml")
    parser.add_argument("--in-process", action="store_true", help="run all nodes in this one process")
    parser.add_argument("--grace", type=float, default=10.0, help="seconds a node gets to stop before SIGKILL")


def run(args: argparse.Namespace) -> int:
    """``fiper launch``."""
    die_with_parent()  # started by a demo or a test fixture: the suite goes with it
    try:
        config = load_config(args.config)
    except (LaunchError, yaml.YAMLError) as error:
        print(f"fiper launch: {error}", file=sys.stderr)
        return 2
    print(f"[launch] {clean_stale().summary()}", flush=True)
    return run_in_process(config) if args.in_process else run_processes(config, args.grace)
