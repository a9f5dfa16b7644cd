"""Where a model or calibration folder named by a relative path is found: one rule for the nodes' parameters,
the launch files and the ``fiper`` commands, so that ``models/sorting/calibration`` works from any
working directory.

An absolute path is taken as it is (its loader names what is missing there). A relative path is looked up, in this order, and the first place where it
exists wins:

1. the working directory (what a relative path always meant: ``models/sorting`` from the checkout's root, or a
   calibration just written by ``fiper calibrate --out``);
2. the share directory of the ``fiper_ros`` package (found on ``AMENT_PREFIX_PATH``, as ``ros2 run`` finds
   packages): the shipped ``models/`` tree is installed there, so ``models/sorting/calibration`` names the
   shipped Sorting calibration wherever the process runs;
3. each directory of ``FIPER_MODELS`` (``:``-separated, like ``PATH``), joined with the path as given:
   ``FIPER_MODELS=/data/fiper`` makes ``pick/calibration`` mean ``/data/fiper/pick/calibration``.

Found nowhere: :class:`DataPathNotFound` names every place that was looked at.
"""
from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from pathlib import Path

from fiper_ros.errors import FiperError

#: Extra directories searched for relative model and calibration paths, after the package share.
MODELS_ENV = "FIPER_MODELS"
#: The package whose share directory holds the shipped ``models/``.
PACKAGE = "fiper_ros"
#: The rule in one line, for the help of the commands' options.
SEARCH_RULE = f"a relative path: from the working directory, else the installed {PACKAGE} share, else ${MODELS_ENV}"


class DataPathNotFound(FiperError):
    """A model or calibration path exists in none of the places of the search rule."""


def package_share() -> Path | None:
    """The installed share directory of ``fiper_ros``, or None when the package is not on the ament index."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory  # noqa: PLC0415

    try:
        return Path(get_package_share_directory(PACKAGE))
    except PackageNotFoundError:
        return None


def search_roots(env: Mapping[str, str] | None = None) -> list[Path]:
    """The directories a relative path is looked up in, in order (after the working directory)."""
    env = os.environ if env is None else env
    share = package_share()
    extra = [Path(d) for d in env.get(MODELS_ENV, "").split(os.pathsep) if d]
    return ([share] if share is not None else []) + extra


def resolve_data_path(path: str | Path, env: Mapping[str, str] | None = None) -> Path:
    """``path`` by the search rule: as given when absolute (its loader names what is missing) or existing from
    the working directory, else under the first root of :func:`search_roots` where it exists."""
    env = os.environ if env is None else env
    given = Path(path)
    if given.is_absolute() or given.exists():
        return given
    roots = search_roots(env)
    for root in roots:
        if (root / given).exists():
            return root / given
    places = ", ".join([str(Path.cwd()), *(str(r) for r in roots)])
    unset = "" if env.get(MODELS_ENV) else f" (${MODELS_ENV} is not set)"
    raise DataPathNotFound(f"{given}: not found in {places}{unset}")


def data_path_argument(value: str) -> Path:
    """``argparse`` type of the commands' model and calibration options: the path by the search rule."""
    try:
        return resolve_data_path(value)
    except DataPathNotFound as error:
        raise argparse.ArgumentTypeError(str(error)) from error
