"""Offline evaluation of FIPER and the baselines (Sec. 5 and App. B-C of the paper); no rclpy.

Modules, one concept each:

- :mod:`.data`: datasets (task name, calibration and test rollouts) and their loading.
- :mod:`.synthetic`: SYNTHETIC benchmark rollouts shaped like the paper's simulation tasks.
- :mod:`.methods`: the seven methods and the per-step score streams they read.
- :mod:`.scoring`: per-step scores of every stream, computed once per dataset, settings and seed.
- :mod:`.cache`: the on-disk score cache and its keys.
- :mod:`.threshold_grid`: core thresholds fitted for many deltas at once (bit-identical).
- :mod:`.sweep`: windows x thresholds x deltas (x FIPER pairs and AND/OR) -> first-alarm steps.
- :mod:`.protocol`: metrics, averaging over deltas, model selection (paper, clean, leave one task out), seeds.
- :mod:`.early`: threshold-free early detection: each configuration's statistic, its AUROC and q-AUC.
- :mod:`.engine`: the whole run over tasks and seeds (scores -> sweep -> metrics -> protocols).
- :mod:`.report`: ``results.md`` (Tables 1 and 2) and ``results.json``.
- :mod:`.plots`: the PNG figures.
- :mod:`.progress`: a stderr progress line.
- :mod:`.offline`: the offline oracle of ``fiper replay --offline`` (bag -> FIPER per step).
- :mod:`.results`: per-rollout prediction results, the same record for the live replay and the oracle.
- :mod:`.verdicts`: each rollout's verdict against its outcome, and the TPR / TNR table of replay and launch.

``fiper evaluate`` is :mod:`fiper_ros.commands.evaluate`.
"""
from __future__ import annotations

from fiper_ros.evaluation.errors import EvaluationError

__all__ = ["EvaluationError", "cache", "data", "early", "engine", "errors", "methods", "offline", "plots", "progress",
           "protocol", "report", "results", "scoring", "sweep", "synthetic", "threshold_grid", "verdicts"]
