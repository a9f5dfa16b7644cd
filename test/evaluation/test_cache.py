"""Score caching: the second computation reads every stream from disk; a changed setting misses."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from fiper_ros.baselines.pca_kmeans import PCAKMeansConfig
from fiper_ros.evaluation.cache import ScoreCache
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.scoring import compute_streams

STREAMS = ["pca_kmeans", "stac", "rnd_oe", "ace"]


def test_second_run_hits_the_cache(tmp_path: Path, tiny_dataset: Dataset, tiny_settings: MethodSettings) -> None:
    cache = ScoreCache(tmp_path)
    first, seconds = compute_streams(tiny_dataset, STREAMS, tiny_settings, 0, cache)
    assert (cache.hits, cache.misses) == (0, len(STREAMS))
    assert len(list(tmp_path.glob("*.npz"))) == len(STREAMS)
    second, again = compute_streams(tiny_dataset, STREAMS, tiny_settings, 0, cache)
    assert (cache.hits, cache.misses) == (len(STREAMS), len(STREAMS))
    assert all(v == 0.0 for v in again.values()) and any(v > 0.0 for v in seconds.values())
    for stream in STREAMS:
        for a, b in zip(first[stream].calibration + first[stream].test, second[stream].calibration + second[stream].test):
            np.testing.assert_array_equal(a, b)


def test_changed_settings_and_seeds_miss(tmp_path: Path, tiny_dataset: Dataset, tiny_settings: MethodSettings) -> None:
    cache = ScoreCache(tmp_path)
    compute_streams(tiny_dataset, ["pca_kmeans", "stac"], tiny_settings, 0, cache)
    changed = replace(tiny_settings, pca_kmeans=PCAKMeansConfig(components=4, clusters=8))
    compute_streams(tiny_dataset, ["pca_kmeans", "stac"], changed, 1, cache)
    # PCA-kmeans misses (new settings and seed); STAC needs no seed and has no settings: it hits.
    assert (cache.hits, cache.misses) == (1, 3)
