"""Example user code on top of the suite: what a policy author writes (README, "Your policy, from the first line
to TPR / TNR").

- :mod:`.minimal_policy`: a stand-in generative policy publishing FIPER's topics with
  :class:`fiper_ros.publishing.FiperPublisher` (``python -m fiper_ros.examples.minimal_policy``).
"""
from __future__ import annotations

__all__ = ["minimal_policy"]
