"""FIPER runtime failure prediction for generative robot policies (ROS 2 suite)."""

__version__ = "0.1.0"
