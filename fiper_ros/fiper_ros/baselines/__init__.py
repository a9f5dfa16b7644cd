"""Baseline failure predictors of the FIPER paper (Sec. 5 "Baselines", App. B.5) that only the offline
evaluation runs.

Pure numpy/torch, never imports rclpy. Every baseline is fitted on the *successful* calibration
rollouts only, is deterministic for a given seed and maps a rollout to per-step scores
(:class:`fiper_ros.baselines.base.Baseline`). Windows, thresholds and metrics are those of
:mod:`fiper_ros.core`, exactly as for RND-OE and ACE. The observation baselines logpZO and PCA-kmeans
are detectors of the core (:mod:`fiper_ros.core.logpzo`, :mod:`fiper_ros.core.pca_kmeans`), which score
with numpy and implement the same interface.

Modules, one baseline each:

- :mod:`.stac`: STAC, temporal action consistency via MMD (Agia et al., 2024).
- :mod:`.rnd_a`: RND on action chunks (adapted from He et al., 2024).
"""
from __future__ import annotations

__all__ = ["base", "rnd_a", "stac"]
