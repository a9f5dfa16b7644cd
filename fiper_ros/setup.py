"""ament_python package of the FIPER failure-prediction suite."""
import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "fiper_ros"
#: The project's version, written once: ``__version__`` of ``fiper_ros/__init__.py`` (read, not imported: the
#: package's dependencies need not be there to build it). Each package.xml repeats it, which a test checks.
VERSION = re.search(r'^__version__ = "([^"]+)"$', (Path(__file__).parent / PACKAGE / "__init__.py").read_text(),
                    re.M).group(1)
#: The shipped policies and calibrations (``fiper_ros/models`` links to the checkout's ``models/``), installed in the
#: share directory, where relative model and calibration paths are looked up (fiper_ros/data_paths.py).
MODELS = "models"
#: Node executables (``ros2 run fiper_ros NAME``): each node module's ``main`` (``detector_node`` scores any detector, its
#: ``detector`` parameter names it; ``rnd_oe_node`` and ``ace_node`` are its presets); ``container`` runs several of the
#: suite's nodes in one process (``ros2 run fiper_ros container rnd_oe_node fusion_node``).
NODES = ("detector_node", "rnd_oe_node", "ace_node", "fusion_node", "supervisor_node", "policy_node", "view_node",
         "container")


def tree(folder: str) -> list[tuple[str, list[str]]]:
    """``data_files`` entries that install every file under ``folder`` into ``share/<package>/<folder>``."""
    by_dir: dict[str, list[str]] = {}
    for path in sorted(Path(folder).rglob("*")):
        if path.is_file():
            by_dir.setdefault(str(path.parent), []).append(str(path))
    return [(f"share/{PACKAGE}/{directory}", files) for directory, files in by_dir.items()]


setup(
    name=PACKAGE,
    version=VERSION,
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", [*glob("config/*.yaml"), "config/fastdds_discovery.xml"]),
        (f"share/{PACKAGE}/config/foxglove", glob("config/foxglove/*.json")),  # the live view's layout
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.*")),  # ros2 launch fiper_ros fiper.launch.yaml
        *tree(MODELS),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="fiper-ros maintainers",
    maintainer_email="fiper-ros@example.com",
    description="FIPER runtime failure prediction for generative robot policies.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["fiper = fiper_ros.cli:main",
                                      *(f"{node} = {PACKAGE}.nodes.{node}:main" for node in NODES)]},
)
