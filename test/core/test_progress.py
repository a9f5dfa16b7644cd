"""The progress detector (core/progress.py): estimated progress and score computed by hand on a 2-D toy, ties, the
one-step rollout, the reference cap, a stalled success, the streaming form bit for bit, its files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core.detector_model import write_model
from fiper_ros.core.progress import (ProgressDetector, ProgressError, ProgressSettings, nearest_mean,
                                     step_progress)
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.step_stream import StepOrderError


def rollout(xs: list[float] | np.ndarray, success: bool | None = True, name: str = "r") -> Rollout:
    """A rollout whose embeddings are ``(x, 0)`` (or the rows given)."""
    xs = np.asarray(xs, dtype=np.float64)
    embeddings = xs if xs.ndim == 2 else np.column_stack([xs, np.zeros_like(xs)])
    return Rollout(name, "toy", "id", embeddings, None, 1, success)


#: Three successes on the x axis: 3 steps (p 0, 1/2, 1), 5 steps (p 0, 1/4, ..., 1) and one step (p 1). Their
#: mean is x = 2, so the centred coordinates are exact: references 0..8 at -2, 0, 2 | -2, -1, 0, 1, 2 | 0 with
#: p 0, .5, 1 | 0, .25, .5, .75, 1 | 1; L = (3 + 5 + 1) / 3 = 3, so t / max(L - 1, 1) = t / 2.
TOY = [rollout([0, 2, 4], name="a"), rollout([0, 1, 2, 3, 4], name="b"), rollout([2], name="c")]


@pytest.fixture(scope="module")
def toy() -> ProgressDetector:
    return ProgressDetector.fit([*TOY, rollout([9, 9], success=False)], ProgressSettings(components=2, neighbours=3))


def test_the_fit_by_hand(toy: ProgressDetector) -> None:
    assert toy.typical_length == 3.0  # the failure is not fitted on
    np.testing.assert_array_equal(toy.pca.mean, [2.0, 0.0])
    np.testing.assert_array_equal(np.abs(toy.reference[:, 0]), [2, 0, 2, 2, 1, 0, 1, 2, 0])
    np.testing.assert_array_equal(toy.reference_progress, [0, 0.5, 1, 0, 0.25, 0.5, 0.75, 1, 1])


@pytest.mark.parametrize(("x", "expected"), [
    (2.0, (0.5 + 0.5 + 1.0) / 3),  # references 1, 5, 8 at distance 0
    (0.0, (0.0 + 0.0 + 0.25) / 3),  # 0, 3 at 0, then 4 at 1
    (3.5, (1.0 + 0.75 + 1.0) / 3),  # 2, 6, 7 all at 0.5
    # a tie for the last places: 1, 4, 5, 8 all at 0.5; the lower indices 1, 4, 5 win (8 has p = 1)
    (1.5, (0.5 + 0.25 + 0.5) / 3),
])
def test_estimated_progress_by_hand(toy: ProgressDetector, x: float, expected: float) -> None:
    assert toy.estimate(np.array([x, 0.0])) == pytest.approx(expected, abs=1e-15)


def test_an_offset_off_the_references_plane_changes_no_neighbour(toy: ProgressDetector) -> None:
    # y = 1 adds the same 1 to every squared distance (the second component is the y axis)
    assert toy.estimate(np.array([1.5, 1.0])) == toy.estimate(np.array([1.5, 0.0]))


def test_scores_by_hand(toy: ProgressDetector) -> None:
    # s(t) = max(0, t / 2 - p_hat): on pace at t = 0, then ahead of the estimated progress
    scores = toy.scores(np.array([[0.0, 0], [1.5, 0], [2, 0], [2, 0], [3.5, 0]]))
    np.testing.assert_allclose(scores, [0.0, 0.5 - 5 / 12, 1 - 2 / 3, 1.5 - 2 / 3, 2 - 11 / 12], rtol=0, atol=1e-15)
    assert toy.scores(np.array([[4.0, 0]]))[0] == 0.0  # ahead of pace: 0, not negative


def test_ties_go_to_the_lower_reference_index() -> None:
    reference = np.array([[1.0], [-1.0], [1.0], [0.0], [-1.0]])
    progress = np.array([0.1, 0.2, 0.4, 0.8, 0.9])
    # distances 1, 1, 1, 0, 1: the nearest is 3, then the lowest of the tied 0, 1, 2, 4
    assert nearest_mean(reference, progress, np.array([0.0]), 2) == pytest.approx((0.8 + 0.1) / 2)
    assert nearest_mean(reference, progress, np.array([0.0]), 3) == pytest.approx((0.8 + 0.1 + 0.2) / 3)
    assert nearest_mean(reference, progress, np.array([0.0]), 5) == pytest.approx(np.mean(progress))
    assert nearest_mean(reference, progress, np.array([0.0]), 9) == pytest.approx(np.mean(progress))


def test_the_progress_of_a_fit_step() -> None:
    np.testing.assert_array_equal(step_progress(1), [1.0])
    np.testing.assert_array_equal(step_progress(2), [0.0, 1.0])
    np.testing.assert_array_equal(step_progress(5), [0.0, 0.25, 0.5, 0.75, 1.0])


def test_one_step_successes_only() -> None:
    # every reference has p = 1 and L = 1: the pace t / max(L - 1, 1) is t, so s(t) = max(0, t - 1)
    detector = ProgressDetector.fit([rollout([0.0], name="a"), rollout([1.0], name="b")],
                                    ProgressSettings(neighbours=1))
    assert detector.typical_length == 1.0
    np.testing.assert_array_equal(detector.scores(np.array([[0.0, 0], [5, 0], [0, 0], [0, 0]])), [0, 0, 1, 2])


def test_the_reference_set_is_a_seeded_subsample_in_fit_order() -> None:
    line = [rollout(np.arange(9.0), name="line"), rollout([100.0], success=False)]  # p = i / 8 tells the step
    capped = ProgressSettings(components=1, max_reference=4)
    first, again, other = (ProgressDetector.fit(line, capped, seed) for seed in (1, 1, 2))
    steps = first.reference_progress * 8
    assert first.reference.shape == (4, 1) and len(set(steps)) == 4  # without replacement
    assert list(steps) == sorted(steps)  # in fit order
    np.testing.assert_array_equal(np.abs(first.reference[:, 0]), np.abs(steps - 4.0))  # the steps' projections
    np.testing.assert_array_equal(first.reference, again.reference)  # seeded
    assert any(not np.array_equal(first.reference_progress, ProgressDetector.fit(line, capped, seed).reference_progress)
               for seed in (2, 3, 4, 5))
    assert other.pca.mean[0] == 4.0 and other.typical_length == 9.0  # projection and L from every step


def test_components_are_capped_at_the_rank() -> None:
    detector = ProgressDetector.fit([rollout(np.eye(3)[:2] * 5.0)], ProgressSettings(components=32))
    assert detector.pca.basis.shape == (1, 3)  # two steps: one centred direction


def _arc(rng: np.random.Generator, length: int, name: str) -> Rollout:
    """A success along a quarter circle, with a little noise."""
    angle = np.linspace(0.0, np.pi / 2, length)
    return rollout(np.column_stack([np.cos(angle), np.sin(angle)]) + 0.01 * rng.normal(size=(length, 2)), name=name)


def test_a_stalled_copy_of_a_success_scores_higher() -> None:
    rng = np.random.default_rng(0)
    detector = ProgressDetector.fit([_arc(rng, int(rng.integers(18, 23)), f"s{i}") for i in range(10)])
    success = _arc(rng, 20, "new").embeddings
    stalled = np.concatenate([success[:8], np.repeat(success[8:9], 12, axis=0), success[8:]])
    assert detector.scores(success).sum() < 0.5
    assert detector.scores(stalled).sum() > 5.0 * detector.scores(success).sum()
    assert detector.scores(stalled).max() > detector.scores(success).max() + 0.3


@st.composite
def _fit_and_rollouts(draw: st.DrawFn) -> tuple[ProgressDetector, list[np.ndarray]]:
    dim = draw(st.integers(1, 5))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    fit = [rollout(rng.normal(size=(int(rng.integers(1, 12)), dim)), name=f"f{i}")
           for i in range(draw(st.integers(1, 4)))]
    chosen = ProgressSettings(components=draw(st.integers(1, 4)), neighbours=draw(st.integers(1, 6)),
                              max_reference=draw(st.integers(1, 30)))
    detector = ProgressDetector.fit(fit, chosen, seed=draw(st.integers(0, 5)))
    rollouts = [draw(st.sampled_from([1.0, 3.0, 1e3])) * rng.normal(size=(int(rng.integers(1, 25)), dim))
                .astype(draw(st.sampled_from([np.float32, np.float64]))) for _ in range(2)]
    return detector, rollouts


@settings(max_examples=150, deadline=None, derandomize=True, database=None)
@given(_fit_and_rollouts())
def test_the_streaming_form_gives_the_whole_rollout_scores_to_the_bit(case: tuple[ProgressDetector,
                                                                                  list[np.ndarray]]) -> None:
    detector, rollouts = case
    stream = detector.stream()
    for embeddings in rollouts:
        stream.reset()
        streamed = np.array([stream.update(t, x) for t, x in enumerate(embeddings)])
        assert np.array_equal(streamed, detector.scores(embeddings))
        assert (streamed >= 0).all()


def test_the_streaming_form_keeps_the_step_order() -> None:
    detector = ProgressDetector.fit(TOY, ProgressSettings(components=2, neighbours=3))
    stream = detector.stream()
    assert stream.history == ProgressDetector.history == 0
    assert stream.update(0, np.array([0.0, 0])) == 0.0
    with pytest.raises(StepOrderError, match="expected policy step 1, got 2"):
        stream.update(2, np.array([2.0, 0]))
    with pytest.raises(ProgressError):
        stream.update(1, np.array([np.nan, 0]))
    assert stream.next_step == 1  # a rejected input leaves the stream as it was
    stream.skip_to(3)  # steps 1 and 2 lost: step 3 reads only its own embedding
    assert stream.update(3, np.array([2.0, 0])) == detector.scores(np.zeros((4, 2)) + [2.0, 0])[3]


@pytest.mark.parametrize(("embedding", "message"), [
    (np.zeros(3), r"shape \(2\)"),
    (np.zeros((1, 2)), r"shape \(2\)"),
    (np.array([np.inf, 0.0]), "NaN/inf"),
    (np.array(["a", "b"]), "not numbers"),
])
def test_malformed_embeddings_are_refused_in_one_line(toy: ProgressDetector, embedding: np.ndarray,
                                                      message: str) -> None:
    with pytest.raises(ProgressError, match=message) as error:
        toy.estimate(embedding)
    assert "\n" not in str(error.value)


def test_malformed_rollouts_settings_and_fits_are_refused(toy: ProgressDetector) -> None:
    with pytest.raises(ProgressError, match=r"^embeddings must have shape \(T, 2\) with no empty axis, got \(0, 2\)$"):
        toy.scores(np.zeros((0, 2)))
    with pytest.raises(ProgressError, match="NaN/inf"):
        toy.scores(np.array([[0.0, 0.0], [np.nan, 0.0]]))
    diagonal = ProgressDetector.fit([rollout(np.array([[0.0, 0.0], [1.0, 1.0]]))])  # basis (1, 1) / sqrt(2)
    with pytest.raises(ProgressError, match="too large to project"):
        diagonal.estimate(np.array([1.5e308, 1.5e308]))
    with pytest.raises(ProgressError, match="neighbours must be an integer >= 1"):
        ProgressSettings(neighbours=0)
    with pytest.raises(ProgressError, match="successful rollouts: none given"):
        ProgressDetector.fit([rollout([1.0, 2.0], success=False), rollout([1.0], success=None)])
    with pytest.raises(ProgressError, match="different embedding sizes"):
        ProgressDetector.fit([rollout([1.0]), rollout(np.zeros((2, 3)))])


def test_save_and_load_keep_the_model_and_its_scores(toy: ProgressDetector, tmp_path: Path) -> None:
    toy.save(tmp_path)
    loaded = ProgressDetector.load(tmp_path)
    assert loaded.digest() == toy.digest()
    assert loaded.settings == toy.settings and loaded.seed == toy.seed
    probe = np.random.default_rng(0).normal(size=(12, 2))
    assert np.array_equal(loaded.scores(probe), toy.scores(probe))
    assert ProgressDetector.fit(TOY, ProgressSettings(components=2, neighbours=2)).digest() != toy.digest()
    with pytest.raises(ProgressError, match="missing"):
        ProgressDetector.load(tmp_path / "nowhere")
    description = json.loads((tmp_path / "progress.json").read_text())
    (tmp_path / "progress.json").write_text(json.dumps({**description, "typical_length": 4.0}))
    with pytest.raises(ProgressError, match="progress.json: content digest mismatch"):
        ProgressDetector.load(tmp_path)
    # a consistent file of an impossible model (written with its own digest) is refused by the model's checks
    write_model(tmp_path, "progress", 1, {**toy.describe(), "typical_length": 0.5}, toy.arrays())
    with pytest.raises(ProgressError, match=r"progress.json: not a progress model \(ProgressError: typical length"):
        ProgressDetector.load(tmp_path)
