"""ament_python package of the FIPER failure-prediction suite."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "fiper_ros"
#: Node executables (``ros2 run fiper_ros NAME``): each node module's ``main``.
NODES = ("rnd_oe_node", "ace_node", "fusion_node", "supervisor_node", "policy_node")

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
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
