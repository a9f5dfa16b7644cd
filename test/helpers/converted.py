"""What ``fiper convert`` wrote: the rollouts of its bags by source file, read back with the bag reader."""
from __future__ import annotations

from pathlib import Path

import yaml

from fiper_ros.bagio.reader import find_bags
from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.core.rollout import Rollout


def read_converted(out: Path) -> dict[str, tuple[str, Rollout]]:
    """source file -> (split, rollout) over the bags written into ``out`` (and its task folders)."""
    result = {}
    for bag in find_bags([out]):
        custom = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["custom_data"]
        sources = yaml.safe_load(custom["rollout_sources"])
        for rollout in read_rollouts(bag):
            result[sources[rollout.rollout_id]] = (custom["split"], rollout)
    return result
