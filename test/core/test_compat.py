"""The paper and reference (authors' code) profiles differ exactly where documented."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.ace import ace_score, step_entropies
from fiper_ros.core.calibration import CalibrationSettings
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.profiles import PAPER, REFERENCE, get_profile
from fiper_ros.core.scores import act_score


def test_paper_ace_is_the_public_ace_score() -> None:
    actions = np.random.default_rng(0).normal(size=(32, 8, 3))
    cell = np.full(3, 0.2)
    assert act_score(actions, cell, PAPER) == ace_score(actions, cell)


def test_reference_ace_is_a_buffered_mean_plus_epsilon() -> None:
    actions = np.random.default_rng(1).normal(size=(32, 8, 3))
    cell = np.full(3, 0.2)
    expected = step_entropies(actions, cell, 0.01).mean() + 1e-6
    assert act_score(actions, cell, REFERENCE) == pytest.approx(expected, abs=1e-15)


def test_range_buffer_can_move_samples_between_cells() -> None:
    # range 1, cell 0.5: unbuffered bins [0, .5), [.5, 1] hold 1 + 3 samples; with the 1% buffer the range
    # is [-0.01, 1.01], three bins [-.01, .49), [.49, .99), [.99, 1.01] hold 1 + 2 + 1 samples.
    actions = np.array([0.0, 0.6, 0.6, 1.0])[:, None, None]
    assert step_entropies(actions, np.array([0.5]))[0] == pytest.approx(0.8112781244591328)
    assert step_entropies(actions, np.array([0.5]), 0.01)[0] == pytest.approx(1.5)


def test_profile_fields() -> None:
    assert (PAPER.conformal, PAPER.band_sign, PAPER.extension) == (True, "upper", "last")
    assert (REFERENCE.conformal, REFERENCE.band_sign, REFERENCE.extension) == (False, "lower", "mean")
    assert get_profile("reference") is REFERENCE
    with pytest.raises(ChoiceError, match="profile"):
        get_profile("fast")


def test_new_profile_fields() -> None:
    assert (PAPER.band_rule, PAPER.ace_binning, PAPER.metrics_rule) == ("paper", "paper", "paper")
    assert (REFERENCE.band_rule, REFERENCE.ace_binning, REFERENCE.metrics_rule) == ("reference",) * 3
    assert CalibrationSettings(profile="reference").threshold_settings().band_rule == "reference"
    assert CalibrationSettings().threshold_settings().band_rule == "paper"


def test_reference_ace_bins_in_float32() -> None:
    # the float32 edge sample of test_ace: three cells in the reference profile, two in float64
    edge = 0.23999999463558197
    actions = np.array([0.0, edge, 1.0])[:, None, None]
    assert act_score(actions, np.array([0.25]), REFERENCE) == pytest.approx(np.log2(3) + 1e-6, abs=1e-15)
    buffered = replace(PAPER, range_buffer=0.01)
    assert act_score(actions, np.array([0.25]), buffered) == pytest.approx(0.9182958340544896, abs=1e-15)
