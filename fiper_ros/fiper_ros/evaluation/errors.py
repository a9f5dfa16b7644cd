"""The offline evaluation's user error: what every error of :mod:`fiper_ros.evaluation` derives from."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class EvaluationError(FiperError):
    """Data, a calibration or settings the offline evaluation or the replay oracle refuses."""
