"""Nothing half-written: outputs are built under a temporary name beside the target and renamed at the end."""
from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fiper_ros.bagio.errors import BagError


def temporary_sibling(path: Path) -> Path:
    """A hidden, process-unique name in the directory of ``path`` (same file system: rename is atomic)."""
    return path.parent / f".{path.name}.partial-{os.getpid()}"


def remove(path: Path) -> None:
    """Delete a file or directory tree if it exists."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _check_parents(path: Path) -> None:
    """Refuse an output below a file: its nearest existing ancestor must be a directory."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise BagError(f"{path}: {parent} is not a directory")
            return


def check_new(path: Path, overwrite: bool = False) -> None:
    """Refuse an existing output unless ``overwrite``; make sure its parent directory exists."""
    if path.exists() and not overwrite:
        raise BagError(f"{path} exists already (choose another name or pass --force)")
    _check_parents(path)
    path.parent.mkdir(parents=True, exist_ok=True)


def commit(temporary: Path, path: Path, overwrite: bool = False) -> None:
    """Move the finished ``temporary`` to ``path`` (replacing an existing ``path`` only if ``overwrite``)."""
    if path.exists():
        if not overwrite:
            remove(temporary)
            raise BagError(f"{path} appeared while it was being written; output left out")
        remove(path)
    temporary.rename(path)


@contextmanager
def atomic_output(path: Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write; on success it becomes ``path``, on any error it is removed.

    The temporary path does not exist yet: the caller creates a file or a directory there.
    """
    path = Path(path)
    check_new(path, overwrite)
    temporary = temporary_sibling(path)
    remove(temporary)
    try:
        yield temporary
    except BaseException:
        remove(temporary)
        raise
    commit(temporary, path, overwrite)


def check_directory(directory: Path) -> None:
    """Refuse an output directory that exists as something else (a file), or lies below a file."""
    if directory.exists() and not directory.is_dir():
        raise BagError(f"{directory} exists and is not a directory")
    _check_parents(directory)


@contextmanager
def atomic_files(directory: Path) -> Iterator[Path]:
    """Yield an empty staging directory beside ``directory``; on success its files move into
    ``directory`` (created if needed; same-named files replaced, others left), on any error nothing
    moves: a failed run adds and changes nothing there."""
    directory = Path(directory)
    check_directory(directory)
    staging = temporary_sibling(directory)
    remove(staging)
    staging.mkdir(parents=True)
    try:
        yield staging
        directory.mkdir(exist_ok=True)
        for file in sorted(staging.iterdir()):
            file.replace(directory / file.name)
    finally:
        remove(staging)
