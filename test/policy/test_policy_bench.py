"""The policy benchmark times every shipped model it finds and only those."""
from __future__ import annotations

from pathlib import Path

import pytest

from fiper_ros.bench import policy_bench

MODELS = Path(__file__).resolve().parents[2] / "models"


def test_bench_times_embed_and_sample_of_each_model_found(tmp_path: Path) -> None:
    (tmp_path / "sorting").symlink_to(MODELS / "sorting")
    (tmp_path / "pusht").mkdir()  # no policy.yaml: not a model
    rows = policy_bench.run(tmp_path, iterations=2, warmup=0)
    assert [(model.split()[0], name) for model, name, _, _ in rows] == [("sorting", "embed"), ("sorting", "sample B chunks")]
    assert rows[0][0] == "sorting (flow, B = 32, H = 8, D = 2)"
    assert all(0 < p50 <= p99 for _, _, p50, p99 in rows)


def test_bench_exits_non_zero_without_models(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert policy_bench.main(["--models", str(tmp_path)]) == 1
    assert "no policy model" in capsys.readouterr().err
