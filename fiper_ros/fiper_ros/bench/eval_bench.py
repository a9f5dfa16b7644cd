"""Speed of the evaluation engine on the SYNTHETIC benchmark (3 tasks, paper shapes, 240 test rollouts each).

Run: ``python -m fiper_ros.bench.eval_bench`` (or ``make bench-eval``). Prints the score-computation
time per task (all eight methods' streams, default settings and split, one seed; 0 when read from the
cache, ``--fresh`` forces a computation) and the time of the full sweep with cached scores: 8 methods x 3
tasks x 50 windows (+ cumulative) x 10 deltas x 4 threshold types (FIPER: the coarse (w_O, w_A) grid
plus the diagonal, AND and OR; the elapsed time: its one configuration), metrics included, against the
60 s target.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see fiper_ros.commands.evaluate

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

from fiper_ros.evaluation.cache import DEFAULT_DIRECTORY, ScoreCache
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.engine import EngineSettings, score_all, sweep_all
from fiper_ros.evaluation.protocol import run_protocol
from fiper_ros.evaluation.synthetic import TASKS, make_task

TARGET_SWEEP_S = 60.0


def main(argv: list[str] | None = None) -> int:
    """Print the timings; exit status 0 (the target is reported, not enforced)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--test", type=int, default=240, help="synthetic test rollouts per task")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_DIRECTORY)
    parser.add_argument("--fresh", action="store_true", help="compute the scores in a temporary cache")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    logging.getLogger("fiper_ros.core.thresholds").setLevel(logging.ERROR)
    datasets = []
    for task in TASKS:
        rollouts = make_task(task, test=args.test)
        datasets.append(Dataset(task, rollouts.calibration, rollouts.test))
    settings = EngineSettings(progress=False)
    with tempfile.TemporaryDirectory() as temporary:
        cache = ScoreCache(temporary if args.fresh else args.cache_dir)
        out = sys.stdout
        out.write(f"{'stage':44s} seconds\n")
        for dataset in datasets:
            _, computing = score_all([dataset], settings, cache)
            state = "computed" if computing > 0 else "cached"
            out.write(f"{'scores ' + dataset.task + ' (' + state + ')':44s} {computing:7.1f}\n")
        start = time.perf_counter()
        scores, _ = score_all(datasets, settings, cache)
        loaded = time.perf_counter()
        outcome = sweep_all(datasets, scores, settings)
        run_protocol("paper", outcome.groups, outcome.metrics["all"], outcome.metrics["all"], settings.methods,
                     settings.default_window, settings.default_kind, infinite=outcome.infinite,
                     held_out=outcome.held_out["all"])
        swept = time.perf_counter()
    configurations = len(outcome.groups) * len(settings.sweep.deltas)
    out.write(f"{'read cached scores (3 tasks)':44s} {loaded - start:7.1f}\n")
    out.write(f"{f'sweep + metrics + selection ({configurations} configs/task)':44s} {swept - loaded:7.1f}"
              f"  ({(swept - loaded) / TARGET_SWEEP_S:.2f} of the {TARGET_SWEEP_S:g} s target)\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
