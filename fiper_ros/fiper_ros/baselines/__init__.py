"""Baseline failure predictors of the FIPER paper (Sec. 5 "Baselines", App. B.5).

Pure numpy/torch, never imports rclpy. Every baseline is fitted on the *successful* calibration
rollouts only, is deterministic for a given seed and maps a rollout to per-step scores
(:class:`fiper_ros.baselines.base.Baseline`). Windows, thresholds and metrics are those of
:mod:`fiper_ros.core`, exactly as for RND-OE and ACE.

Modules, one baseline each:

- :mod:`.stac`: STAC, temporal action consistency via MMD (Agia et al., 2024).
- :mod:`.logpzo`: logpZO, flow matching on observation embeddings (Xu et al., 2025).
- :mod:`.pca_kmeans`: PCA + k-means distance on observation embeddings (Liu et al., 2024).
- :mod:`.rnd_a`: RND on action chunks (adapted from He et al., 2024).
"""
from __future__ import annotations

__all__ = ["base", "logpzo", "pca_kmeans", "rnd_a", "stac"]
