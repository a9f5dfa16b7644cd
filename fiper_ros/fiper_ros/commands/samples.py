"""Synthetic sample bags shaped like the paper's real-world tasks (bags/README.md).

``python -m fiper_ros.commands.samples --out bags/`` writes, per set, the source data in the original
layout into a temporary directory (FIPER rollout pickles for Pretzel, Sentinel episode DataFrames
for PushChair), converts it with ``fiper convert`` into ``<set>/calibration_rollouts`` and
``<set>/test_rollouts``, and fits ``<set>/calibration`` with ``fiper calibrate`` on the calibration
bag. Everything is a function of ``--seed``; the data is labelled synthetic in the set's name and in
every bag's ``custom_data``. NONE OF IT COMES FROM A ROBOT.

The generator: a task is a smooth path through an 8-D latent "task phase" space, projected to the
embedding size, and a smooth end-effector path; every policy step the B sampled chunks follow the
path with a small per-sample spread (low action entropy). A failing rollout, from an onset on, drifts
out of distribution along a fixed embedding direction and its sampled chunks spread over many ACE
cells (entropy rises), while its progress stalls until the step limit. Values are rounded to float16
precision to keep the bags small.

``python -m fiper_ros.commands.samples --observation-only BAG... --out DIR`` writes observation-only copies of
bags instead (:func:`observation_only`: no action batches, no joint states), e.g. of the
shipped sets for an observation-only calibration and replay.
"""
from __future__ import annotations

import argparse
import math
import pickle
import sys
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fiper_ros.bagio.atomic import atomic_output
from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.commands import convert
from fiper_ros.commands.calibrate import calibrate_bags
from fiper_ros.converters.options import ConvertOptions
from fiper_ros.core.calibration import CalibrationSettings
from fiper_ros.errors import FiperError, fail
from fiper_ros.interface.topics import ACTIONS_TOPIC, JOINT_STATES_TOPIC

LATENT_DIM = 8
#: The end-effector path spans about this many metres; sample spread and OOD spread relative to it.
PATH_SCALE = 0.3
ID_SPREAD = 0.004
OOD_SPREAD = 0.06
#: Embedding drift of a failure, per embedding dimension at full strength (ID values are ~0.7 rms).
OOD_DRIFT = 1.2
#: Steps from a failure's onset to full drift and spread.
RAMP_STEPS = 6


@dataclass(frozen=True)
class SampleSet:
    """One synthetic sample set.

    Attributes:
        name: Directory under the output (ends in ``_synthetic``).
        task: Task name in the data.
        layout: ``"fiper"`` (rollout pickles) or ``"sentinel"`` (episode DataFrames).
        embedding_dim: ``E``.
        batch_size: ``B``.
        horizon: ``H``.
        action_dim: ``D`` of the source data.
        positions: Channels holding the end-effector position in the source data.
        exec_steps: ``h``.
        max_steps: Step limit: failures run until it.
        success_lengths: Range of a success's length (policy steps, inclusive).
        ood_scenarios: Scenario names of the test rollouts (FIPER subtypes / Sentinel split codes).
        calibration: Keyword arguments of the set's :class:`CalibrationSettings`.
        calibration_rollouts: Successful calibration rollouts.
        test_successes: Successful test rollouts.
        test_failures: Failed test rollouts.
    """

    name: str
    task: str
    layout: str
    embedding_dim: int
    batch_size: int
    horizon: int
    action_dim: int
    positions: tuple[int, int]
    exec_steps: int
    max_steps: int
    success_lengths: tuple[int, int]
    ood_scenarios: tuple[str, ...]
    calibration: dict[str, object] = field(default_factory=dict)
    calibration_rollouts: int = 10
    test_successes: int = 5
    test_failures: int = 5


#: The sample sets' 10 calibration successes are too few to split at delta 0.1 (a CP constant threshold needs
#: at least 9 conformal rollouts): they are calibrated on the same data on purpose, as the paper's Remark 1
#: does; that calibration is not covered by Proposition 1 (its file says so). They are demonstration data.
SAMPLE_SPLIT = "same"

PRETZEL = SampleSet("pretzel_synthetic", "pretzel", "fiper", embedding_dim=512, batch_size=30, horizon=16,
                    action_dim=5, positions=(0, 3), exec_steps=8, max_steps=70, success_lengths=(40, 62),
                    ood_scenarios=("rope_vertical", "rope_horizontal", "rope_rotation"),
                    calibration={"window": 5, "threshold": "cp_constant", "delta": 0.1,
                                 "split": SAMPLE_SPLIT})
PUSHCHAIR = SampleSet("pushchair_synthetic", "pushchair", "sentinel", embedding_dim=96, batch_size=256, horizon=16,
                      action_dim=7, positions=(1, 4), exec_steps=4, max_steps=22, success_lengths=(8, 16),
                      ood_scenarios=("na", "hh", "ss"),
                      calibration={"window": 3, "threshold": "cp_constant", "delta": 0.1,
                                   "split": SAMPLE_SPLIT})
SETS = {"pretzel": PRETZEL, "pushchair": PUSHCHAIR}


def _half(values: np.ndarray) -> np.ndarray:
    """float32 values rounded to float16 precision (compressible, still float32 in the data)."""
    return values.astype(np.float16).astype(np.float32)


class TaskModel:
    """The fixed synthetic 'policy' of a task: latent path, embedding projection, end-effector path."""

    def __init__(self, spec: SampleSet, rng: np.random.Generator) -> None:
        self.spec = spec
        self.projection = rng.normal(0.0, 1.0 / math.sqrt(LATENT_DIM), (LATENT_DIM, spec.embedding_dim))
        self.frequencies = rng.uniform(0.5, 2.0, LATENT_DIM)
        self.phases = rng.uniform(0.0, 2 * math.pi, LATENT_DIM)
        drift = rng.normal(size=spec.embedding_dim)
        # Out of distribution = away from the ID manifold: remove the projection's row space.
        basis, _ = np.linalg.qr(self.projection.T)
        drift -= basis @ (basis.T @ drift)
        self.drift = drift / np.linalg.norm(drift) * math.sqrt(spec.embedding_dim)  # about 1 per dimension
        self.extra = rng.uniform(-1.0, 1.0, (spec.action_dim, 2))

    def path(self, progress: np.ndarray) -> np.ndarray:
        """End-effector positions ``[..., 3]`` at task progress in [0, 1]."""
        p = np.asarray(progress)[..., None]
        return PATH_SCALE * np.concatenate(
            [np.sin(np.pi * p), 0.5 * (1 - np.cos(2 * np.pi * p)), 0.4 * p], axis=-1)

    def rollout(self, rng: np.random.Generator, length: int, onset: int | None,
                shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Embeddings ``[T, E]`` and action batches ``[T, B, H, D]`` of one rollout.

        Args:
            rng: Randomness of this rollout.
            length: Policy steps ``T``.
            onset: First step of a failure's drift (``None``: a success).
            shift: Constant OOD offset of a successful OOD rollout, in units of the failure drift.
        """
        spec = self.spec
        nominal = length if onset is None else rng.integers(*spec.success_lengths)
        strength = np.zeros(length)
        if onset is not None:
            strength = np.clip((np.arange(length) - onset + 1) / RAMP_STEPS, 0.0, 1.0)
        # Progress stalls during a failure.
        rate = 1.0 / max(nominal - 1, 1) * (1.0 - 0.8 * strength)
        progress = np.concatenate([[0.0], np.cumsum(rate[:-1])]).clip(0.0, 1.0)

        latent = np.sin(2 * np.pi * self.frequencies * progress[:, None] + self.phases)
        latent += rng.normal(0.0, 0.1, LATENT_DIM) + rng.normal(0.0, 0.05, (length, LATENT_DIM))
        embeddings = latent @ self.projection + rng.normal(0.0, 0.05, (length, spec.embedding_dim))
        embeddings += (OOD_DRIFT * (strength + shift))[:, None] * self.drift

        env_step = 1.0 / (max(nominal - 1, 1) * spec.exec_steps)
        ahead = progress[:, None] + env_step * np.arange(spec.horizon)[None, :]
        positions = self.path(ahead)[:, None, :, :]  # [T, 1, H, 3]
        spread = ID_SPREAD + OOD_SPREAD * strength[:, None, None, None]
        offsets = rng.normal(0.0, 1.0, (length, spec.batch_size, 1, 3))
        wander = np.cumsum(rng.normal(0.0, 0.25, (length, spec.batch_size, spec.horizon, 3)), axis=2)
        positions = positions + spread * (offsets + wander / math.sqrt(spec.horizon))

        actions = np.empty((length, spec.batch_size, spec.horizon, spec.action_dim))
        other = [c for c in range(spec.action_dim) if not spec.positions[0] <= c < spec.positions[1]]
        for channel in other:  # orientation / gripper-like channels: smooth in the progress
            amplitude, phase = self.extra[channel]
            actions[..., channel] = amplitude * np.cos(np.pi * ahead + phase)[:, None, :]
        actions[..., spec.positions[0]:spec.positions[1]] = positions
        return _half(embeddings.astype(np.float32)), _half(actions.astype(np.float32))


@dataclass(frozen=True)
class Episode:
    """One generated rollout before it is written in a source layout."""

    split: str
    scenario: str
    success: bool
    embeddings: np.ndarray
    actions: np.ndarray


def episodes(spec: SampleSet, seed: int) -> list[Episode]:
    """Calibration successes, then test successes and failures (OOD scenarios in turn)."""
    rng = np.random.default_rng(seed)
    model = TaskModel(spec, rng)
    result = []
    for _ in range(spec.calibration_rollouts):
        length = int(rng.integers(spec.success_lengths[0], spec.success_lengths[1] + 1))
        embeddings, actions = model.rollout(rng, length, None)
        result.append(Episode("calibration", "id", True, embeddings, actions))
    for i in range(spec.test_successes + spec.test_failures):
        success = i < spec.test_successes
        scenario = spec.ood_scenarios[i % len(spec.ood_scenarios)]
        if success:
            length = int(rng.integers(spec.success_lengths[0], spec.success_lengths[1] + 1))
            embeddings, actions = model.rollout(rng, length, None, shift=float(rng.uniform(0.0, 0.15)))
        else:
            length = int(rng.integers(spec.success_lengths[1], spec.max_steps + 1))
            onset = int(rng.integers(length // 4, length // 2 + 1))
            embeddings, actions = model.rollout(rng, length, onset)
        result.append(Episode("test", scenario, success, embeddings, actions))
    return result


def write_fiper_layout(spec: SampleSet, items: list[Episode], root: Path) -> Path:
    """FIPER rollout pickles: ``<root>/<task>/rollouts/{calibration,test}/rollout_NNN_{s,f}_.pkl``."""
    task_dir = root / spec.task
    for i, episode in enumerate(items):
        directory = task_dir / "rollouts" / episode.split
        directory.mkdir(parents=True, exist_ok=True)
        subtype = "ca" if episode.split == "calibration" else episode.scenario
        steps = [{"obs_embedding": e, "action_pred": a, "action": a[0, 0]} for e, a in zip(episode.embeddings, episode.actions)]
        content = {"metadata": {"successful": episode.success, "rollout_subtype": subtype, "task": spec.task,
                                "synthetic": True}, "rollout": steps}
        marker = "s" if episode.success else "f"
        with (directory / f"rollout_{i:03d}_{marker}_.pkl").open("wb") as stream:
            pickle.dump(content, stream)
    return task_dir


def write_sentinel_layout(spec: SampleSet, items: list[Episode], root: Path) -> Path:
    """Sentinel episode DataFrames: ``<root>/<task>/<task>_<code>/episodes/epNNNN.pkl``."""
    import pandas  # noqa: PLC0415 - only this layout needs pandas

    task_dir = root / spec.task
    counters: dict[str, int] = {}
    for episode in items:
        code = "ca" if episode.split == "calibration" else episode.scenario
        directory = task_dir / f"{spec.task}_{code}" / "episodes"
        directory.mkdir(parents=True, exist_ok=True)
        frame = pandas.DataFrame({
            "timestep": np.arange(len(episode.embeddings)) * spec.exec_steps,
            "encoder_feat": list(episode.embeddings),
            "sampled_actions": list(episode.actions),
            "executed_action": [a[0] for a in episode.actions],
            "success": episode.success,
        })
        index = counters.get(code, 0)
        counters[code] = index + 1
        frame.to_pickle(directory / f"ep{index:04d}.pkl")
    return task_dir


def make_set(spec: SampleSet, out: Path, seed: int, overwrite: bool = False) -> Path:
    """Generate, convert and calibrate one sample set into ``out/<spec.name>``."""
    target = out / spec.name
    settings = CalibrationSettings(seed=seed, **spec.calibration)  # type: ignore[arg-type]
    with atomic_output(target, overwrite) as staging, tempfile.TemporaryDirectory(prefix="fiper-samples-") as tmp:
        writer = write_fiper_layout if spec.layout == "fiper" else write_sentinel_layout
        source = writer(spec, episodes(spec, seed), Path(tmp))
        options = ConvertOptions(task=spec.task, exec_steps=spec.exec_steps if spec.layout == "fiper" else 0,
                                 max_steps=spec.max_steps, synthetic=True)
        convert.convert(spec.layout, source, staging, options)
        calibrate_bags([staging / convert.bag_name("calibration")], staging / "calibration", settings, quiet=True)
    return target


#: What an observation-only copy leaves out: the action batches and the joint states only ACE reads.
ACTION_TOPICS = (ACTIONS_TOPIC, JOINT_STATES_TOPIC)


def observation_only(source: Path, out: Path, overwrite: bool = False) -> Path:
    """Write ``out``: the bag ``source`` without its action batches and joint states (observation-only data),
    every other message as recorded, byte for byte, at its log time; ``custom_data`` without the action
    layout (B, H, D, action space) and its ``source`` naming the copy."""
    with BagReader(source) as reader, BagWriter(out, overwrite=overwrite) as writer:
        info = reader.info
        origin = f"observation-only copy of {source}" + (f" ({info.source})" if info.source else "")
        writer.info = replace(info, batch_size=0, horizon=0, action_dim=0, action_space="", source=origin)
        for message in reader.messages([t for t in reader.topics if t not in ACTION_TOPICS]):
            writer.write(message.topic, message.log_time_ns, message.raw, message.msgtype)
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m fiper_ros.commands.samples --out bags/`` (or ``--observation-only BAG... --out DIR``)."""
    parser = argparse.ArgumentParser(prog="python -m fiper_ros.commands.samples", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="directory to write the sets into (e.g. bags/)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the generated data and the calibrations")
    parser.add_argument("--sets", nargs="+", choices=sorted(SETS), default=sorted(SETS), help="sets to make")
    parser.add_argument("--observation-only", nargs="+", type=Path, metavar="BAG",
                        help="instead: write observation-only copies of these bags into --out (same names)")
    parser.add_argument("--force", action="store_true", help="replace existing sets")
    args = parser.parse_args(argv)
    for bag in args.observation_only or ():
        try:
            print(observation_only(bag, args.out / bag.name, args.force))
        except FiperError as error:
            return fail("samples", error)
    for name in () if args.observation_only else args.sets:
        try:
            target = make_set(SETS[name], args.out, args.seed, args.force)
        except FiperError as error:
            return fail("samples", error)
        size = sum(p.stat().st_size for p in target.rglob("*") if p.is_file())
        print(f"{target}: {size / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
