"""Latency of the FIPER core per policy step: ACE, RND-OE (batch 1), fusion, and all together (the two
streaming monitors and the fusion node's fuser, as the nodes run them, without DDS); the streaming forms of the
progress and action-consistency detectors.

Run: ``python -m fiper_ros.bench.core_bench`` (or ``make bench-core``). Prints p50/p99 in ms and the
ratio of each p50 to its target (ACE <= 1 ms, RND-OE small <= 2 ms, all together <= 3 ms).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import numpy as np

from fiper_ros.core.ace import ace_score
from fiper_ros.core.calibration import Calibration, CalibrationSettings, DetectorPart, Layout, TaskPart
from fiper_ros.core.consistency import ActionConsistency
from fiper_ros.core.detectors import ACE, RND_OE
from fiper_ros.core.monitor import DetectorMonitor
from fiper_ros.core.progress import ProgressDetector, ProgressSettings
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.rnd_train import untrained_rnd
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scorers import AceScorer, RndOeScorer
from fiper_ros.core.thresholds import Threshold
from fiper_ros.runtime.alarm import AlarmFuser, DetectorScore

ACE_SHAPES = ((256, 16, 3), (30, 16, 5), (32, 8, 3))
EMBEDDING_DIMS = (64, 128, 512)
TARGET_ACE_MS = 1.0
TARGET_RND_MS = 2.0
TARGET_TOTAL_MS = 3.0
#: The PushT layout: embedding size, then ``(B, H, D)`` and ``h``.
PUSHT_EMBEDDING = 64
PUSHT_CHUNKS, PUSHT_EXEC = (256, 16, 2), 8
#: Embedding sizes of the progress detector's rows (the default settings: 32 components, 4096 references).
PROGRESS_DIMS = (PUSHT_EMBEDDING, 1024)


def measure(function: Callable[[int], object], iterations: int, warmup: int) -> tuple[float, float]:
    """p50 and p99 in ms of ``function(i)`` over ``iterations`` calls after ``warmup`` calls."""
    for i in range(warmup):
        function(i)
    times = np.empty(iterations)
    for i in range(iterations):
        start = time.perf_counter()
        function(i)
        times[i] = time.perf_counter() - start
    p50, p99 = np.percentile(times * 1e3, [50, 99])
    return float(p50), float(p99)


def _calibration(embedding_dim: int, ace_shape: tuple[int, int, int]) -> Calibration:
    """A calibration with an untrained small RND-OE: the per-step cost does not depend on training."""
    _, horizon, dims = ace_shape
    threshold = Threshold("cp_constant", 0.05, np.full(100, 1e9))
    settings = CalibrationSettings(window=5)
    profile = settings.profile_obj
    detectors = {RND_OE: DetectorPart(RndOeScorer(untrained_rnd(embedding_dim, RNDConfig.small()), profile), threshold),
                 ACE: DetectorPart(AceScorer(np.ones(dims), settings.options(), "ee_position", profile), threshold)}
    return Calibration(settings, Layout(embedding_dim, dims, horizon, horizon // 2, "ee_position"),
                       {"": TaskPart(detectors, 0)})


def _fit_rollouts(rng: np.random.Generator, embedding_dim: int, steps: int = 5000) -> list[Rollout]:
    """Successes of 250 random steps each, ``steps`` in all (more than the 4096 references progress keeps), with
    PushT-shaped action batches of a single sample (only sample 0 is fitted on)."""
    return [Rollout(f"fit-{i}", "bench", "id", rng.normal(size=(250, embedding_dim)),
                    rng.normal(size=(250, 1, *PUSHT_CHUNKS[1:])), PUSHT_EXEC, True) for i in range(steps // 250)]


def detector_rows(rng: np.random.Generator, iterations: int,
                  warmup: int) -> list[tuple[str, float, float, float | None]]:
    """The streaming ``update`` of progress (default settings, a full reference set) and action consistency."""
    rows: list[tuple[str, float, float, float | None]] = []
    for dim in PROGRESS_DIMS:
        detector = ProgressDetector.fit(_fit_rollouts(rng, dim), ProgressSettings())
        stream, inputs = detector.stream(), rng.normal(size=(8, dim)).astype(np.float32)
        p50, p99 = measure(lambda i, s=stream, x=inputs: s.update(s.next_step, x[i % 8]), iterations, warmup)
        rows.append((f"progress update E={dim} (k {detector.pca.basis.shape[0]}, {detector.reference.shape[0]} "
                     "references)", p50, p99, None))
    consistency = ActionConsistency.fit(_fit_rollouts(rng, 1, 2000))
    stream = consistency.stream()
    batches = [rng.normal(size=PUSHT_CHUNKS).astype(np.float32) for _ in range(8)]
    p50, p99 = measure(lambda i: stream.update(stream.next_step, batches[i % 8]), iterations, warmup)
    rows.append((f"consistency update (B,H,D)={PUSHT_CHUNKS} h={PUSHT_EXEC}", p50, p99, None))
    return rows


def run(iterations: int, warmup: int) -> list[tuple[str, float, float, float | None]]:
    """All measurements as ``(name, p50, p99, target_ms)``."""
    rng = np.random.default_rng(0)
    rows: list[tuple[str, float, float, float | None]] = []
    for shape in ACE_SHAPES:
        batches = [rng.normal(size=shape).astype(np.float32) for _ in range(8)]
        cell = np.full(shape[2], 0.03 * 6.0)  # alpha = 0.03 of a range of about 6 sigma
        p50, p99 = measure(lambda i, b=batches, c=cell: ace_score(b[i % 8], c), iterations, warmup)
        rows.append((f"ACE (B,H,D)={shape}", p50, p99, TARGET_ACE_MS))
    for name, config, target in (("small", RNDConfig.small(), TARGET_RND_MS), ("paper", RNDConfig.paper(), None)):
        for dim in EMBEDDING_DIMS:
            model = untrained_rnd(dim, config)
            inputs = rng.normal(size=(8, dim)).astype(np.float32)
            n = iterations if name == "small" else max(iterations // 10, 20)
            p50, p99 = measure(lambda i, m=model, x=inputs: m.score_one(x[i % 8]), n, warmup)
            rows.append((f"RND-OE {name} score_one E={dim}", p50, p99, target))
    calibration = _calibration(512, ACE_SHAPES[0])
    fuser = AlarmFuser(calibration.settings.combine)
    fuser.start(1, 0)

    def fuse(i: int, obs_exceeded: bool, act_exceeded: bool) -> object:
        fuser.add(DetectorScore("rnd_oe", 1, i, 2.0 if obs_exceeded else 0.0, 1.0, i, True, obs_exceeded), i)
        return fuser.add(DetectorScore("ace", 1, i, 2.0 if act_exceeded else 0.0, 1.0, i, True, act_exceeded), i)

    p50, p99 = measure(lambda i: fuse(i, i % 3 == 0, i % 2 == 0), iterations, warmup)
    rows.append(("fusion step (AlarmFuser.add of both scores)", p50, p99, None))
    observation, action = DetectorMonitor(calibration, RND_OE), DetectorMonitor(calibration, ACE)
    fuser.start(2, 0)
    embeddings = rng.normal(size=(8, 512)).astype(np.float32)
    actions = [rng.normal(size=ACE_SHAPES[0]).astype(np.float32) for _ in range(8)]
    step = iter(range(10**9))

    def together(i: int) -> object:
        t = next(step)
        obs, act = observation.update(t, embeddings[i % 8]), action.update(t, (actions[i % 8], None))
        fuser.add(DetectorScore("rnd_oe", 2, t, obs.windowed, obs.threshold, t, obs.complete, bool(obs.exceeded)), t)
        return fuser.add(DetectorScore("ace", 2, t, act.windowed, act.threshold, t, act.complete, bool(act.exceeded)), t)

    p50, p99 = measure(together, iterations, warmup)
    name = "together: both monitors' update and AlarmFuser.add (ACE 256x16x3, RND-OE small E=512, windows, fusion)"
    rows.append((name, p50, p99, TARGET_TOTAL_MS))
    return rows + detector_rows(rng, iterations, warmup)


def main(argv: list[str] | None = None) -> int:
    """Print the table; exit status 0 (targets are reported, not enforced)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    args = parser.parse_args(argv)
    rows = run(args.iterations, args.warmup)
    width = max(len(name) for name, *_ in rows)
    sys.stdout.write(f"{'measurement'.ljust(width)}  p50 ms  p99 ms  p50/target\n")
    for name, p50, p99, target in rows:
        ratio = f"{p50 / target:.2f} of {target:g} ms" if target else "-"
        sys.stdout.write(f"{name.ljust(width)}  {p50:6.3f}  {p99:6.3f}  {ratio}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
