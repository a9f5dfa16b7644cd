"""``ros2 launch fiper_ros fiper.launch.py [name:=value ...]``: the FIPER suite of ``fiper.launch.yaml``.

The YAML file beside this one is the only description of the suite (``fiper launch`` reads it too); this file
only includes it, so that ``ros2 launch`` takes either name. The arguments given on the command line reach the
YAML's ``arg`` tags (an included description shares the launch configurations), and
``ros2 launch fiper_ros fiper.launch.py --show-args`` lists them (the path is a plain string, so the YAML can be
read before the launch runs). Needs ``launch`` and ``launch_ros`` (a full ROS 2 install; this repository's pip
wheels have neither, docs/install.md).
"""
from pathlib import Path

from launch import LaunchDescription
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import AnyLaunchDescriptionSource

#: The suite's launch file, installed beside this one (share/fiper_ros/launch/).
SUITE = Path(__file__).with_name("fiper.launch.yaml")


def generate_launch_description() -> LaunchDescription:
    """The suite: ``fiper.launch.yaml`` included as it is."""
    return LaunchDescription([IncludeLaunchDescription(AnyLaunchDescriptionSource(str(SUITE)))])
