"""Score caching: the second computation reads every stream from disk; a changed setting or split misses."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from fiper_ros.core.pca_kmeans import PCAKMeansConfig
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
        a, b = first[stream], second[stream]
        assert a.fit is not None and b.fit is not None  # the default split conformal: a fit part for the shapes
        assert len(a.fit) == len(b.fit) == len(a.conformal) == len(tiny_dataset.calibration_successes) // 2
        for x, y in zip(a.fit + a.conformal + a.test, b.fit + b.conformal + b.test):
            np.testing.assert_array_equal(x, y)


def test_changed_settings_and_seeds_miss(tmp_path: Path, tiny_dataset: Dataset, tiny_settings: MethodSettings) -> None:
    cache = ScoreCache(tmp_path)
    compute_streams(tiny_dataset, ["pca_kmeans", "stac"], tiny_settings, 0, cache)
    changed = replace(tiny_settings, pca_kmeans=PCAKMeansConfig(components=4, clusters=8))
    compute_streams(tiny_dataset, ["pca_kmeans", "stac"], changed, 1, cache)
    # PCA-kmeans misses (new settings and seed); STAC needs no seed and has no settings: it hits.
    assert (cache.hits, cache.misses) == (1, 3)


def test_the_split_is_part_of_the_key(tmp_path: Path, tiny_dataset: Dataset, tiny_settings: MethodSettings) -> None:
    cache = ScoreCache(tmp_path)
    streams = ["ace", "stac", "elapsed"]
    compute_streams(tiny_dataset, streams, tiny_settings, 0, cache)
    assert (cache.hits, cache.misses) == (0, 3)
    # another seed is another split: ACE's R_d is fitted anew; STAC and the elapsed time fit nothing
    compute_streams(tiny_dataset, streams, tiny_settings, 1, cache)
    assert (cache.hits, cache.misses) == (2, 4)
    same = replace(tiny_settings, split="same")
    compute_streams(tiny_dataset, streams, same, 0, cache)
    assert (cache.hits, cache.misses) == (4, 5)
    # with the same data for everything ACE has no seed: seed 1 reads seed 0's scores
    scores, _ = compute_streams(tiny_dataset, streams, same, 1, cache)
    assert (cache.hits, cache.misses) == (7, 5)
    assert scores["ace"].fit is None and len(scores["ace"].conformal) == len(tiny_dataset.calibration_successes)
