"""FIPER core: failure prediction scores, thresholds and metrics (Römer et al., NeurIPS 2025).

Pure Python (numpy, optional pinocchio; torch only to train: :mod:`.rnd_train`, :mod:`.logpzo_train`,
:mod:`.torch_mlp`); never imports rclpy. The ROS nodes, the bag replay
and the offline evaluation all call :mod:`fiper_ros.core.monitor`, so their results are identical.

Modules, one concept each:

- :mod:`.rollout`: the rollout record and its ``.npz`` container.
- :mod:`.data_split`: the calibration / test split of data that comes without one (a seeded fraction per task).
- :mod:`.ace`: action-chunk entropy, eq. (4) and App. A.1.
- :mod:`.kinematics`: joint-space actions to end-effector positions (App. A.1, last paragraph).
- :mod:`.mlp`: MLP builder and numpy forward pass shared by RND-OE and the RND-A baseline.
- :mod:`.rnd_oe`: random network distillation on observation embeddings, eq. (1) and App. A.2.
- :mod:`.pca`: mean-centred principal components of embeddings.
- :mod:`.progress`: the progress detector (elapsed time ahead of the estimated task progress).
- :mod:`.consistency`: single-sample action consistency (overlap of consecutive executed chunks).
- :mod:`.pca_kmeans`: the PCA-kmeans detector (distance to the nearest centroid; a baseline of App. B.5).
- :mod:`.logpzo`: the logpZO detector (flow matching on embeddings; a baseline of App. B.5), scored in numpy.
- :mod:`.detector_model`: what those detectors share: the input check, the JSON + npz files with a digest.
- :mod:`.step_stream`: the step order of a detector's streaming form.
- :mod:`.window`: score aggregation, eqs. (2) and (5).
- :mod:`.thresholds`: calibrated thresholds, Sec. 4.3 and App. A.3.
- :mod:`.combination`: one conformal threshold over a combination of detectors (normalised, voted).
- :mod:`.combine_mode`: the combine modes (and, or, max, kth), without numpy.
- :mod:`.equalisation`: the detectors' tails equalised before a joint combination (quantile or tail maps).
- :mod:`.fusion`: the votes of the detectors' decisions: eq. (7)'s AND/OR, max and kth:K.
- :mod:`.metrics`: TPR, TNR, accuracy, DT and TWA, App. B.4.
- :mod:`.profiles`: the "paper" and "reference" (authors' code) profiles.
- :mod:`.detectors`: every detector's name, label and what it reads (one registry).
- :mod:`.scorers`: each declarable detector fitted on successes and scored, whole-rollout and streaming.
- :mod:`.calibration_file`: reading ``calibration.yaml`` without torch (what a calibration declares).
- :mod:`.calibration`: a calibration's settings, model, fitting and files (one module each).
- :mod:`.auto`: choosing a calibration's configuration from successes alone (``fiper calibrate --auto``).
- :mod:`.transfer`: ``--auto``'s ``transfer`` rule: a prior learned on other tasks' labelled rollouts, its file.
- :mod:`.monitor`: streaming and vectorised failure prediction.
- :mod:`.errors`: :class:`CoreError`, what every error of the core derives from, and :class:`.errors.ChoiceError`
  (an unknown detector, combine or profile).
"""
from __future__ import annotations

from fiper_ros.core.errors import CoreError

__all__ = ["CoreError", "ace", "auto", "calibration", "calibration_file", "combination", "combine_mode", "consistency",
           "data_split", "detector_model", "detectors", "equalisation", "errors", "fusion", "kinematics", "logpzo",
           "metrics", "mlp", "monitor", "pca", "pca_kmeans", "profiles", "progress", "rnd_oe", "rollout", "scorers",
           "scores", "step_stream", "thresholds", "transfer", "window"]
