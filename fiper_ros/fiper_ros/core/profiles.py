"""Method profiles: the paper's definitions (default) and the authors' code ("reference").

The paper is the specification. The authors' public code differs in a few places (see
``docs/method.md``); the ``"reference"`` profile reproduces those differences so that numbers from
their pipeline can be matched. Each field below is one deviation.
"""

from __future__ import annotations

from dataclasses import dataclass

from fiper_ros.core.errors import ChoiceError

PROFILE_NAMES = ("paper", "reference")


@dataclass(frozen=True)
class Profile:
    """Settings that distinguish the paper from the authors' code.

    Attributes:
        name: ``"paper"`` or ``"reference"``.
        ace_reduce: ``"sum"`` over the horizon (eq. 4) or ``"mean"`` (authors' code).
        score_epsilon: Added to every per-step score, RND-OE and ACE (authors' code: 1e-6).
        range_buffer: ACE: widen each step's sample range by this fraction on both sides.
        alpha: Default ACE cell size factor.
        conformal: Conformal quantiles (paper) or plain ``np.quantile`` (authors' code) for the
            CP thresholds.
        band_sign: CP band score sign, ``"upper"`` (paper) or ``"lower"`` (authors' code).
        extension: Threshold extension beyond the calibration length.
        min_support: Support rule for per-step statistics (``None``: the default rule; 1: none).
        ranges_from_all: ``R_d`` over all calibration rollouts, failed ones included (authors'
            code), instead of the successful ones only (paper: ``D_c`` holds successes).
        dt_mode: Detection time normalisation for :func:`fiper_ros.core.metrics.evaluate`.
        band_rule: How ``cp_band`` splits its curves and models the band
            (:data:`fiper_ros.core.thresholds.BAND_RULES`): ``"paper"``, a seeded split and the floored
            standard deviation; ``"reference"``, the authors' split (the longest curve plus the first half of
            the others in the order given), filter, maximum-deviation modulation and its fill-ins.
        ace_binning: How ACE assigns samples to cells (:data:`fiper_ros.core.ace.BINNINGS`): ``"paper"``,
            float64 ``floor((x - low) / cell)``; ``"reference"``, the authors' float32 ``np.arange`` edges
            and ``np.digitize``, with the cell ``alpha * R_d`` in float32.
        metrics_rule: Empty classes and rounding of :func:`fiper_ros.core.metrics.evaluate`
            (:data:`fiper_ros.core.metrics.METRIC_RULES`): ``"paper"``, NaN where a class is empty;
            ``"reference"``, TPR / TNR 0 and DT 1.0 there, every metric rounded to 6 decimals in float32.
    """

    name: str
    ace_reduce: str
    score_epsilon: float
    range_buffer: float
    alpha: float
    conformal: bool
    band_sign: str
    extension: str
    min_support: int | None
    ranges_from_all: bool
    dt_mode: str
    band_rule: str
    ace_binning: str
    metrics_rule: str


PAPER = Profile(
    name="paper",
    ace_reduce="sum",
    score_epsilon=0.0,
    range_buffer=0.0,
    alpha=0.03,
    conformal=True,
    band_sign="upper",
    extension="last",
    min_support=None,
    ranges_from_all=False,
    dt_mode="paper",
    band_rule="paper",
    ace_binning="paper",
    metrics_rule="paper",
)

REFERENCE = Profile(
    name="reference",
    ace_reduce="mean",
    score_epsilon=1e-6,
    range_buffer=0.01,
    alpha=0.03,
    conformal=False,
    band_sign="lower",
    extension="mean",
    min_support=1,
    ranges_from_all=True,
    dt_mode="reference",
    band_rule="reference",
    ace_binning="reference",
    metrics_rule="reference",
)


def get_profile(name: str) -> Profile:
    """The profile called ``name``; :class:`~fiper_ros.core.errors.ChoiceError` naming the profiles otherwise."""
    profiles = {"paper": PAPER, "reference": REFERENCE}
    if name not in profiles:
        raise ChoiceError(f"unknown profile {name!r}; expected one of {PROFILE_NAMES}")
    return profiles[name]
