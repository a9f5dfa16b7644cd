"""tools/equal_promise.py: configurations compared at equal promise, by hand."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("equal_promise", ROOT / "tools" / "equal_promise.py")
assert _spec is not None and _spec.loader is not None
equal_promise = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(equal_promise)

DELTAS = [0.05, 0.1]


def row(method: str, combine: str, kind: str, twa_a: list[float | None], twa_b: list[float | None],
        window: str = "5") -> dict[str, object]:
    return {"method": method, "window": window, "threshold": kind, "combine": combine,
            "metrics": {"a": {"twa": twa_a}, "b": {"twa": twa_b}}}


def test_an_or_is_read_at_delta_over_its_thresholds_and_the_rest_at_the_promise() -> None:
    sweep = [row("fiper", "or", "cp_band", [0.6, 0.9], [0.8, 0.9]),          # promise 0.1: delta 0.05 -> 0.7
             row("rnd_oe", "", "cp_band", [0.5, 0.75], [0.7, 0.75]),         # promise 0.1: delta 0.1 -> 0.75
             row("rnd_oe", "", "cp_scaled", [0.9, 0.7], [0.9, 0.72], "9"),   # 0.71: not the best of rnd_oe
             row("logpzo", "", "time_varying", [1.0, 1.0], [1.0, 1.0]),      # no promise: left out
             row("trio", "or", "cp_band", [0.9, 0.9], [0.9, 0.9]),           # OR of 3: delta 0.0333 not swept
             row("fiper_joint", "max", "cp_band", [0.6, None], [0.6, 0.8])]  # +inf on one task: left out
    best = equal_promise.best_at_promise(sweep, DELTAS, {"trio": ["a", "b", "c"], "fiper_joint": ["rnd_oe", "ace"]},
                                         0.1)
    assert best == {("fiper", "or"): (pytest.approx(0.7), "5", "cp_band"),
                    ("rnd_oe", ""): (pytest.approx(0.75), "5", "cp_band")}
    assert equal_promise.best_at_promise(sweep, DELTAS, {"trio": ["a", "b", "c"]}, 0.05) == {
        ("rnd_oe", ""): (pytest.approx(0.9), "9", "cp_scaled"),
        ("fiper_joint", "max"): (pytest.approx(0.6), "5", "cp_band")}  # defined at 0.05; the OR would need 0.025


def test_the_command_prints_each_promise_best_first(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    results = {"tasks": {"a": {}, "b": {}}, "settings": {"deltas": DELTAS, "combinations": {}},
               "sweep": [row("fiper", "or", "cp_band", [0.6, 0.9], [0.8, 0.9]),
                         row("rnd_oe", "", "cp_band", [0.5, 0.75], [0.7, 0.75])]}
    (run / "results.json").write_text(json.dumps(results))
    assert equal_promise.main([str(run), "--promises", "0.1"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == [f"{run} (a, b)", "  promise 0.1: rnd_oe - 0.750 (w 5, cp_band); fiper or 0.700 (w 5, cp_band)"]
