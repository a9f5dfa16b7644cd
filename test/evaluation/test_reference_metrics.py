"""``fiper evaluate --profile reference`` computes every metric by the authors' rule (core.metrics, ``metrics_rule``
``"reference"``): an empty class gives TPR 0 and DT 1.0 (and a TWA), and every value is rounded to 6 decimals and
cast to float32. The paper profile leaves the same cells undefined."""

from __future__ import annotations

import json
import math
from pathlib import Path

from fiper_ros.cli import main
from fiper_ros.core.metrics import authors_rounding
from fiper_ros.core.rollout import RolloutSet
from fiper_ros.evaluation.data import Dataset


def _sweep(tmp_path: Path, tiny_dataset: Dataset, profile: str) -> tuple[list[dict], int]:
    """results.json's sweep of a run on the tiny data set's test successes alone (no failure: no positives), and
    their number."""
    test = [r for r in tiny_dataset.test if r.success]
    data = tmp_path / "no_failures.npz"
    RolloutSet(tiny_dataset.calibration, test).save_npz(data)
    out = tmp_path / profile
    assert main(["evaluate", "--data", f"sorting={data}", "--methods", "elapsed,stac", "--profile", profile,
                 "--windows", "1-3", "--default-window", "1", "--max-pool", "2", "--deltas", "0.2,0.3",
                 "--no-cache", "--no-plots", "--quiet", "--out", str(out)]) == 0
    return json.loads((out / "results.json").read_text())["sweep"], len(test)


def test_the_reference_profile_gives_the_authors_metrics_for_an_empty_class(tmp_path: Path,
                                                                           tiny_dataset: Dataset) -> None:
    sweep, n = _sweep(tmp_path, tiny_dataset, "reference")
    fractions = {k / n for k in range(n + 1)}
    cells = [(entry, d) for entry in sweep for d in range(2) if entry["metrics"]["sorting"]["twa"][d] is not None]
    assert len(cells) > 20
    rounded = 0
    for entry, d in cells:
        values = {metric: series[d] for metric, series in entry["metrics"]["sorting"].items()}
        assert values["tpr"] == 0.0 and values["dt"] == 1.0, entry  # no failure: no positive, no true positive
        assert all(v == authors_rounding(v) for v in values.values()), entry  # 6 decimals, float32
        assert math.isclose(values["twa"], values["tnr"] / 2, abs_tol=1e-6) and values["acc"] == values["twa"]
        rounded += values["tnr"] not in fractions  # k / n itself is not what is reported
    assert rounded > 0
    paper, _ = _sweep(tmp_path, tiny_dataset, "paper")
    assert all(entry["metrics"]["sorting"][metric] == [None, None] for entry in paper for metric in ("twa", "tpr", "dt"))
