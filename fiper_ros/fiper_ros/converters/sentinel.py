"""Loader of Sentinel / STAC rollout data (Agia et al.; docs/bags.md, "Converters").

Layout: one pickled pandas DataFrame per episode, ``.../<split dir>/episodes/ep%04d.pkl``, one row per
policy inference with ``timestep`` (environment steps, +h per row), ``encoder_feat`` ``(E,)``,
``sampled_actions`` float32 ``(B, H, D)``, ``executed_action`` ``(H, D)`` and ``success`` (the
episode's outcome, repeated on every row). The split is a code in a directory name on the way to the
file (a ``_``/``-``-separated token): ``ca`` = calibration, ``na`` = ID test, ``hh`` / ``ss`` = OOD test.

PushChair actions have D = 7 with the end-effector position in channels 1-3 (inferred from the data
description, unverified): with ``--channels auto`` (default) a D = 7 batch keeps channels ``1:4``,
any other D keeps all channels.

Unpickling runs code from the file: load pickles only from sources you trust.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from fiper_ros.bagio.errors import BagError
from fiper_ros.converters.options import AUTO, Budget, ConvertOptions, Converted, select_channels
from fiper_ros.core.rollout import ID_SCENARIO, Rollout, RolloutError

#: split code -> (bag split, scenario)
SPLIT_CODES = {"ca": ("calibration", ID_SCENARIO), "na": ("test", ID_SCENARIO), "hh": ("test", "hh"), "ss": ("test", "ss")}
#: Channels kept by ``--channels auto`` for D = 7 (PushChair: positions in 1-3).
PUSHCHAIR_DIMS, PUSHCHAIR_POSITIONS = 7, (1, 4)
COLUMNS = ("timestep", "encoder_feat", "sampled_actions", "success")


def split_code(path: Path, root: Path) -> str:
    """The split code of the nearest directory (below ``root``) whose name has one as a token."""
    for part in reversed(path.relative_to(root).parent.parts):
        for token in re.split(r"[_\-.]", part.lower()):
            if token in SPLIT_CODES:
                return token
    if root.name.lower() in SPLIT_CODES:
        return root.name.lower()
    raise BagError(f"{path}: no split code ({', '.join(SPLIT_CODES)}) in its directory names")


def _frame(path: Path):  # noqa: ANN202 - pandas DataFrame
    import pandas  # noqa: PLC0415 - only this converter needs pandas

    try:
        frame = pandas.read_pickle(path)  # noqa: S301 - trusted sources only (documented)
    except Exception as error:  # any unpickling failure is a bad file
        raise BagError(f"{path}: not a readable pickle ({type(error).__name__}: {error})") from error
    if not isinstance(frame, pandas.DataFrame):
        raise BagError(f"{path}: not a pandas DataFrame but {type(frame).__name__}")
    missing = [c for c in COLUMNS if c not in frame.columns]
    if missing:
        raise BagError(f"{path}: missing column(s) {', '.join(missing)}")
    if frame.empty:
        raise BagError(f"{path}: the episode has no rows")
    return frame.sort_values("timestep")


def load_episode(path: Path, code: str, task: str, options: ConvertOptions) -> Rollout:
    """One episode DataFrame as a core Rollout."""
    frame = _frame(path)
    timesteps = frame["timestep"].to_numpy(dtype=np.int64)
    try:
        embeddings = np.stack([np.asarray(v, dtype=np.float32).ravel() for v in frame["encoder_feat"]])
        actions = np.stack([np.asarray(v, dtype=np.float32) for v in frame["sampled_actions"]])
    except ValueError as error:
        raise BagError(f"{path}: rows of different shapes ({error})") from error
    if actions.ndim != 4:
        raise BagError(f"{path}: sampled_actions must be (B, H, D), got {actions.shape[1:]}")
    outcomes = set(bool(v) for v in frame["success"])
    if len(outcomes) != 1:
        raise BagError(f"{path}: column success differs between rows")
    channels = options.channels
    if channels == AUTO:
        channels = PUSHCHAIR_POSITIONS if actions.shape[-1] == PUSHCHAIR_DIMS else AUTO
    steps = np.diff(timesteps)
    exec_steps = options.exec_steps or (int(np.median(steps)) if steps.size else options.exec_steps_for(task, path))
    try:
        return Rollout(
            rollout_id=path.stem, task=task, scenario=SPLIT_CODES[code][1], embeddings=embeddings,
            actions=select_channels(actions, channels, path), exec_steps=exec_steps, success=outcomes.pop(),
            action_space=options.action_space, metadata={"env_steps": timesteps.tolist(), "max_steps": options.max_steps},
        )
    except RolloutError as error:
        raise BagError(f"{path}: {error}") from error


def load(src: Path, options: ConvertOptions) -> Converted:
    """Every episode under ``src`` by split (ca -> calibration, others -> test), with its source name."""
    if not src.is_dir():
        raise BagError(f"{src}: no such directory")
    files = sorted(p for p in src.rglob("ep*.pkl") if p.parent.name == "episodes")
    if not files:
        raise BagError(f"{src}: no episodes/ep*.pkl files (Sentinel layout <split dir>/episodes/ep0000.pkl)")
    task = options.task or src.name
    converted: Converted = {}
    budget = Budget(options.max_mb)
    for path in files:
        code = split_code(path, src)
        budget.check_file(path, path.stat().st_size)
        rollout = load_episode(path, code, task, options)
        budget.take(str(path), rollout)
        converted.setdefault(SPLIT_CODES[code][0], []).append((rollout, str(path.relative_to(src))))
    return dict(sorted(converted.items()))
