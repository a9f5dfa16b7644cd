"""Training loop: AdamW, warm-up + cosine learning rate, EMA weights, per-epoch checkpoints and resume.

Determinism: the model is initialised from ``seed`` and every epoch draws its shuffling, noise and
augmentation from a generator seeded by ``(seed, epoch)``, so a run resumed from a checkpoint equals
an uninterrupted one (same thread count assumed).
"""
from __future__ import annotations

import copy
import logging
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from .config import PolicyConfig
from .dataset import DemoDataset
from .errors import PolicyError
from .normalizer import RangeNormalizer
from .policy import Policy

LOG = logging.getLogger(__name__)
CHECKPOINT_FILE = "checkpoint.pt"
WARMUP_STEPS = 100


@dataclass(frozen=True)
class Progress:
    """One progress report: epoch (1-based), step within the run, total steps, mean loss, seconds."""

    epoch: int
    step: int
    total_steps: int
    loss: float
    seconds: float


def epoch_generator(seed: int, epoch: int) -> torch.Generator:
    """The random stream of one epoch (shuffling, noise, augmentation)."""
    return torch.Generator().manual_seed(seed * 1_000_003 + epoch)


def _lr_factor(step: int, total: int) -> float:
    if step < WARMUP_STEPS:
        return (step + 1) / WARMUP_STEPS
    progress = (step - WARMUP_STEPS) / max(total - WARMUP_STEPS, 1)
    return 0.5 * (1.0 + math.cos(math.pi * min(progress, 1.0)))


def _ema_update(ema: Policy, model: Policy, step: int, decay: float) -> None:
    d = min(decay, (1.0 + step) / (10.0 + step))
    with torch.no_grad():
        for target, source in zip(ema.parameters(), model.parameters()):
            target.lerp_(source, 1.0 - d)


def print_progress(report: Progress) -> None:
    """Default progress line on stderr."""
    eta = report.seconds / max(report.step, 1) * (report.total_steps - report.step)
    print(f"epoch {report.epoch} step {report.step}/{report.total_steps} loss {report.loss:.4f} "
          f"elapsed {report.seconds / 60:.1f} min eta {eta / 60:.1f} min", file=sys.stderr, flush=True)


def _restore(path: Path, config: PolicyConfig, seed: int, data_hash: str, model: Policy, ema: Policy,
             optimizer: torch.optim.Optimizer, scheduler: torch.optim.lr_scheduler.LRScheduler) -> tuple[int, float]:
    """Load a matching checkpoint into the training state; return ``(epochs done, seconds spent)``."""
    if not path.exists():
        return 0, 0.0
    state: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=False)
    if state["config"] != config.to_dict() or state["seed"] != seed or state["data_hash"] != data_hash:
        LOG.warning("ignoring %s: written with another config, seed or data", path)
        return 0, 0.0
    model.load_state_dict(state["model"])
    ema.load_state_dict(state["ema"])
    optimizer.load_state_dict(state["optimizer"])
    scheduler.load_state_dict(state["scheduler"])
    LOG.info("resumed from %s after epoch %d", path, state["epoch"])
    return int(state["epoch"]), float(state["elapsed"])


def _save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write ``state`` atomically (temporary file + rename)."""
    temporary = path.with_name(path.name + ".tmp")
    torch.save(state, temporary)
    temporary.replace(path)


def train(config: PolicyConfig, demos: str | Path, out: str | Path, run_dir: str | Path, seed: int = 0,
          max_episodes: int | None = None, progress: Callable[[Progress], None] = print_progress,
          report_every: int = 20, stop_after: int | None = None) -> Policy:
    """Train a policy on the demos, checkpointing to ``run_dir`` every epoch; write the EMA weights to ``out``.

    Resumes from ``run_dir/checkpoint.pt`` if it exists and was written with the same config and seed.
    ``stop_after``: end after this many epochs of the ``config.epochs`` schedule (the learning rate follows
    the whole schedule); a later call without it continues from the checkpoint.

    Raises:
        PolicyError: no (successful) demonstrations, demonstrations whose action or proprio dimensions differ from
            the config's, ``stop_after`` not in 1..epochs or a checkpoint already past it.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    dataset = DemoDataset(demos, config.obs_horizon, config.horizon, config.image_size, max_episodes)
    if dataset.actions.shape[-1] != config.action_dim or dataset.proprio.shape[-1] != config.proprio_dim:
        raise PolicyError(f"demos have action/proprio dims {dataset.actions.shape[-1]}/{dataset.proprio.shape[-1]}, "
                          f"config expects {config.action_dim}/{config.proprio_dim}")
    torch.manual_seed(seed)
    model = Policy(config, RangeNormalizer.fit(dataset.actions.numpy()), RangeNormalizer.fit(dataset.proprio.numpy()))
    ema = copy.deepcopy(model)
    optimizer = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay, fused=True)
    steps_per_epoch = max(len(dataset) // config.batch_size, 1)
    total_steps = steps_per_epoch * config.epochs
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: _lr_factor(s, total_steps))
    data_hash = dataset.hash()
    start_epoch, elapsed = _restore(run_dir / CHECKPOINT_FILE, config, seed, data_hash,
                                    model, ema, optimizer, scheduler)
    last_epoch = config.epochs if stop_after is None else stop_after
    if not 1 <= last_epoch <= config.epochs or start_epoch > last_epoch:
        raise PolicyError(f"cannot stop after epoch {last_epoch}: the schedule has {config.epochs} epochs and "
                          f"{run_dir / CHECKPOINT_FILE} holds {start_epoch}")
    LOG.info("training %s: %d parameters, %d samples, %d steps", config.task,
             sum(p.numel() for p in model.parameters()), len(dataset), total_steps)
    loss_value = float("nan")
    for epoch in range(start_epoch, last_epoch):
        began = time.perf_counter()
        generator = epoch_generator(seed, epoch)
        order = torch.randperm(len(dataset), generator=generator)
        model.train()
        running, counted = 0.0, 0
        for index in range(steps_per_epoch):
            batch = dataset.batch(order[index * config.batch_size:(index + 1) * config.batch_size],
                                  config.image_shift, generator)
            embedding = model.encode(batch.images, batch.proprio)
            loss = model.loss(embedding.repeat_interleave(config.noise_draws, dim=0),
                              batch.actions.repeat_interleave(config.noise_draws, dim=0), generator)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            optimizer.step()
            scheduler.step()
            step = epoch * steps_per_epoch + index + 1
            _ema_update(ema, model, step, config.ema_decay)
            running, counted = running + loss.item(), counted + 1
            if (index + 1) % report_every == 0 or index + 1 == steps_per_epoch:
                loss_value, running, counted = running / counted, 0.0, 0
                progress(Progress(epoch + 1, step, total_steps, loss_value,
                                  elapsed + time.perf_counter() - began))
        elapsed += time.perf_counter() - began
        _save_checkpoint(run_dir / CHECKPOINT_FILE, {
            "config": config.to_dict(), "seed": seed, "data_hash": data_hash, "epoch": epoch + 1, "elapsed": elapsed,
            "model": model.state_dict(), "ema": ema.state_dict(), "optimizer": optimizer.state_dict(),
            "scheduler": scheduler.state_dict()})
    ema.save(out, {"seed": seed, "epochs": config.epochs, "epochs_trained": last_epoch,
                   "training_seconds": round(elapsed, 1),
                   "training_samples": len(dataset), "training_episodes": dataset.episodes,
                   "demos": str(demos), "data_hash": data_hash, "final_loss": round(loss_value, 5),
                   "parameters": sum(p.numel() for p in ema.parameters()), "torch": str(torch.__version__),
                   "threads": torch.get_num_threads()})
    return ema
