"""ament_python package of the MuJoCo Franka stand-in."""
import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "sim_bridge"
#: The version of its package.xml (the project's one version, ``fiper_ros.__version__``, which a test checks; this
#: package builds without fiper_ros's sources).
VERSION = re.search(r"<version>([^<]+)</version>", (Path(__file__).parent / "package.xml").read_text()).group(1)

setup(
    name=PACKAGE,
    version=VERSION,
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["assets/**/*"]},
    include_package_data=True,
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.*")),  # ros2 launch sim_bridge bridge.launch.yaml
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="fiper-ros maintainers",
    maintainer_email="fiper-ros@example.com",
    description="MuJoCo Franka stand-in with Sorting, Stacking and PushT tasks.",
    license="Apache-2.0",
    # ``ros2 run sim_bridge bridge_node``; ``sim_bridge`` is the simulation core's command line.
    entry_points={"console_scripts": ["sim_bridge = sim_bridge.cli:main", "bridge_node = sim_bridge.bridge_node:main"]},
)
