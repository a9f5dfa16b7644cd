"""FIPER runtime failure prediction for generative robot policies (ROS 2 suite).

The packages and their layers: docs/architecture.md.
"""

__all__ = ["__version__"]

__version__ = "0.1.0"
