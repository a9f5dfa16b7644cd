"""SYNTHETIC benchmark rollouts shaped like the paper's simulation tasks (Table 4 of the paper).

These are NOT policy rollouts: every number is drawn from a hand-made generative model so the
evaluation engine can be exercised end to end before real simulator rollouts exist. Every rollout's
``metadata["synthetic"]`` is ``True`` and its id starts with ``synthetic-``.

Per task (:data:`TASKS`): ``E`` embedding dims, ``B`` samples of ``H``-step chunks with ``D`` position
channels, ``h`` executed steps, at most ``T`` policy steps. The model of one rollout:

- embeddings: a smooth task-phase path through ``R^E`` (fixed random basis per task) plus noise; an
  OOD scenario shifts it by a fixed scenario offset (benign: the policy still succeeds);
- actions: ``B`` chunks along a smooth end-effector path, sampled from one or two modes (ID
  multimodality at random decision steps), consecutive chunks consistent;
- a failure starts at a random onset: after it, depending on the failure type, the embeddings drift
  away from the calibration distribution ("obs"), the action samples spread over many modes and lose
  their step-to-step consistency ("act"), or both ("both"). Failed rollouts mostly run to ``T``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fiper_ros.core.rollout import ID_SCENARIO, Rollout, RolloutSet

LOG = logging.getLogger(__name__)

OOD_SCENARIOS = ("ood_size", "ood_target")
FAILURE_TYPES = ("both", "obs", "act")
FAILURE_TYPE_WEIGHTS = (0.6, 0.2, 0.2)
#: Test mix: (scenario is OOD, success) -> share of the test rollouts.
TEST_MIX = {(False, True): 0.25, (False, False): 0.2, (True, True): 0.25, (True, False): 0.3}


@dataclass(frozen=True)
class TaskSpec:
    """Shapes of one task: embedding dim, samples, horizon, action dims, executed steps, max steps."""

    name: str
    embedding_dim: int
    samples: int
    horizon: int
    dims: int
    exec_steps: int
    max_steps: int


TASKS: dict[str, TaskSpec] = {
    "sorting": TaskSpec("sorting", 128, 32, 8, 2, 4, 75),
    "stacking": TaskSpec("stacking", 128, 32, 8, 3, 4, 120),
    "push_t": TaskSpec("push_t", 64, 256, 16, 2, 8, 38),
}


class _TaskModel:
    """The fixed random structure of one task (basis, scenario offsets), seeded by the task."""

    def __init__(self, spec: TaskSpec, seed: int) -> None:
        rng = np.random.default_rng([seed, sum(map(ord, spec.name))])
        self.spec = spec
        self.basis = rng.normal(0.0, 1.0, (8, spec.embedding_dim)) / np.sqrt(8.0)
        self.offsets = {name: 0.5 * rng.normal(0.0, 1.0, spec.embedding_dim) for name in OOD_SCENARIOS}

    def embeddings(self, rng: np.random.Generator, phase: np.ndarray, scenario: str) -> np.ndarray:
        """Phase path ``[T, E]`` plus noise and the scenario's offset."""
        frequencies = np.arange(1, 5)
        angles = 2.0 * np.pi * phase[:, None] * frequencies[None, :] + rng.normal(0.0, 0.2, 4)
        features = np.concatenate([np.sin(angles), np.cos(angles)], axis=1)
        out = 2.0 * features @ self.basis + rng.normal(0.0, 0.3, (phase.shape[0], self.spec.embedding_dim))
        return out + self.offsets.get(scenario, 0.0)

    def path(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Random smooth end-effector path parameters: amplitudes and phases ``[D]``."""
        return rng.uniform(0.5, 1.0, self.spec.dims), rng.uniform(0.0, 2.0 * np.pi, self.spec.dims)


def _chunks(model: _TaskModel, rng: np.random.Generator, length: int, total: int, onset: int | None,
            spread: bool) -> np.ndarray:
    """Sampled chunks ``[T, B, H, D]`` along a smooth path; spread over many modes after ``onset``."""
    spec = model.spec
    amplitude, offset = model.path(rng)
    env_steps = np.arange(length)[:, None] * spec.exec_steps + np.arange(spec.horizon)[None, :]
    tau = env_steps / float(total * spec.exec_steps)
    nominal = amplitude * np.sin(2.0 * np.pi * tau[..., None] + offset)  # [T, H, D]
    actions = np.repeat(nominal[:, None], spec.samples, axis=1)
    ramp = (np.arange(spec.horizon) + 1.0) / spec.horizon
    decisions = rng.random(length) < 0.15  # ID multimodality: two modes at decision steps
    for t in np.flatnonzero(decisions):
        direction = rng.normal(0.0, 1.0, spec.dims)
        half = rng.random(spec.samples) < 0.5
        actions[t, half] += 0.1 * ramp[:, None] * direction / np.linalg.norm(direction)
    actions += rng.normal(0.0, 0.01, actions.shape)
    if onset is not None and spread:
        for t in range(onset, length):
            severity = min(1.0, (t - onset + 1) / 5.0)
            modes = rng.normal(0.0, 0.25 * severity, (6, spec.dims))
            pick = rng.integers(0, 6, spec.samples)
            actions[t] += ramp[None, :, None] * modes[pick][:, None, :]
            actions[t] += rng.normal(0.0, 0.05 * severity, (1, 1, spec.dims))
    return actions.astype(np.float32)


def make_rollout(spec: TaskSpec, model: _TaskModel, rng: np.random.Generator, index: int, *, ood: bool,
                 success: bool) -> Rollout:
    """One synthetic rollout of ``spec`` (see the module docstring for the model)."""
    scenario = str(rng.choice(OOD_SCENARIOS)) if ood else ID_SCENARIO
    if success:
        length = int(round(spec.max_steps * rng.uniform(0.55, 0.9)))
    else:
        length = spec.max_steps if rng.random() < 0.6 else int(round(spec.max_steps * rng.uniform(0.6, 1.0)))
    length = max(length, 4)
    total = int(round(spec.max_steps * 0.75))
    phase = np.minimum(np.arange(length) / total, 1.0)
    embeddings = model.embeddings(rng, phase, scenario)
    onset: int | None = None
    failure_type = "none"
    if not success:
        failure_type = str(rng.choice(FAILURE_TYPES, p=FAILURE_TYPE_WEIGHTS))
        onset = int(rng.integers(int(0.2 * length), int(0.6 * length) + 1))
        if failure_type in ("both", "obs"):
            direction = rng.normal(0.0, 1.0, spec.embedding_dim)
            drift = np.clip((np.arange(length) - onset + 1) / 6.0, 0.0, 1.0)
            embeddings = embeddings + 1.5 * drift[:, None] * direction / np.linalg.norm(direction) * np.sqrt(8.0)
    actions = _chunks(model, rng, length, total, onset, failure_type in ("both", "act"))
    metadata = {"synthetic": True, "failure_type": failure_type, "onset": -1 if onset is None else onset}
    return Rollout(
        rollout_id=f"synthetic-{spec.name}-{index:04d}",
        task=spec.name,
        scenario=scenario,
        embeddings=embeddings.astype(np.float32),
        actions=actions,
        exec_steps=spec.exec_steps,
        success=success,
        metadata=metadata,
    )


def make_task(task: str, seed: int = 0, calibration: int = 50, test: int = 240, scale: float = 1.0) -> RolloutSet:
    """A synthetic :class:`RolloutSet`: ``calibration`` ID successes and ``test`` mixed rollouts.

    ``scale`` shrinks ``E``, ``B`` and ``T`` (e.g. 0.25 for fast tests); 1 gives the paper's shapes.
    """
    if task not in TASKS:
        raise ValueError(f"unknown synthetic task {task!r}; expected one of {sorted(TASKS)}")
    spec = TASKS[task]
    if scale != 1.0:
        spec = TaskSpec(spec.name, max(4, int(spec.embedding_dim * scale)), max(8, int(spec.samples * scale)),
                        spec.horizon, spec.dims, spec.exec_steps, max(12, int(spec.max_steps * scale)))
    model = _TaskModel(spec, seed)
    rng = np.random.default_rng([seed, 1, sum(map(ord, task))])
    rollouts = RolloutSet()
    rollouts.calibration = [make_rollout(spec, model, rng, i, ood=False, success=True) for i in range(calibration)]
    counts = {key: int(round(share * test)) for key, share in TEST_MIX.items()}
    counts[(True, False)] += test - sum(counts.values())
    index = calibration
    for (ood, success), count in counts.items():
        for _ in range(count):
            rollouts.test.append(make_rollout(spec, model, rng, index, ood=ood, success=success))
            index += 1
    LOG.info("synthetic %s: %d calibration, %d test rollouts", task, calibration, len(rollouts.test))
    return rollouts


def main(argv: list[str] | None = None) -> int:
    """Write one ``<task>.npz`` per task: ``python -m fiper_ros.evaluation.synthetic --out DIR``; an unknown task of
    ``--tasks`` is refused as argparse refuses a flag (one line, exit 2)."""
    parser = argparse.ArgumentParser(description="Write SYNTHETIC benchmark rollouts (not policy data).")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--calibration", type=int, default=50)
    parser.add_argument("--test", type=int, default=240)
    parser.add_argument("--scale", type=float, default=1.0)
    args = parser.parse_args(argv)
    tasks = args.tasks.split(",")
    unknown = [task for task in tasks if task not in TASKS]
    if unknown:
        parser.error(f"--tasks: unknown {', '.join(map(repr, unknown))}; expected some of {', '.join(TASKS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    for task in tasks:
        path = args.out / f"{task}.npz"
        make_task(task, args.seed, args.calibration, args.test, args.scale).save_npz(path)
        sys.stdout.write(f"wrote {path} (synthetic)\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
