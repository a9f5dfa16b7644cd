"""Mutation testing of fiper_ros.core and fiper_ros.runtime with mutmut 3 (`make mutants`).

    python tools/mutants.py [FILE ...] [--jobs N]     (after `source env.sh`; make mutants does both)

FILE is a path under fiper_ros/fiper_ros, e.g. ``core/fusion.py``: only that file's mutants are tested,
all of them afresh (minutes per file). Without FILE every mutant of core/ and runtime/ without a verdict
is tested (resumable: stop it with Ctrl-C, run it again and it goes on; verdicts stay in .mutmut/mutants/).
When a file under test/ changed since the last run, every surviving mutant is tested again (a test may
have been added to kill it). mutmut shows its progress; a summary per file and every survivor's diff follow.

The work dir .mutmut/ (git-ignored) holds links to the package, test/, models/, bags/, pytest.ini and tools/mutmut.cfg
(as the setup.cfg mutmut reads): mutmut names a mutant after its path from the working directory, and
the tests import ``fiper_ros.core...``, so the package must sit at ``fiper_ros/`` there. mutmut copies it
with its mutants into .mutmut/mutants/ and puts that first on sys.path, ahead of the colcon build.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "fiper_ros" / "fiper_ros"
WORK = ROOT / ".mutmut"
MUTATED = ("core", "runtime")
LINKS = {"fiper_ros": PACKAGE, "test": ROOT / "test", "pytest.ini": ROOT / "pytest.ini",
         "setup.cfg": ROOT / "tools" / "mutmut.cfg",
         # tests read the shipped calibrations and sample bags by their path from the repository root, which is
         # mutants/ inside mutmut's copy (tools/mutmut.cfg copies them there)
         "models": ROOT / "models", "bags": ROOT / "bags"}
# mutmut forks one process per mutant from the one that ran the tests once. GNU OpenMP (torch's thread
# pool) does not survive a fork: the child's first parallel region waits forever for the parent's
# threads (seen: torch.linalg.qr in a forked worker, every mutant a timeout). One thread per worker.
SINGLE_THREADED = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def _prepare_work_dir() -> None:
    """Create .mutmut/ and its links (again, where one points elsewhere)."""
    WORK.mkdir(exist_ok=True)
    for name, target in LINKS.items():
        link = WORK / name
        relative = Path(os.path.relpath(target, WORK))
        if link.is_symlink() and Path(os.readlink(link)) == relative:
            continue
        if link.is_symlink() or link.exists():
            link.unlink()
        link.symlink_to(relative)


def _module_of(file: str) -> str:
    """``core/fusion.py`` -> ``fiper_ros.core.fusion``; a file outside core/ and runtime/ is refused."""
    path = Path(file)
    if path.parts and path.parts[0] == "fiper_ros":  # also accept fiper_ros/core/fusion.py
        path = Path(*path.parts[1:])
    if path.suffix != ".py" or len(path.parts) != 2 or path.parts[0] not in MUTATED or not (PACKAGE / path).is_file():
        raise SystemExit(f"mutants: {file} is not a module of fiper_ros/fiper_ros/{{{','.join(MUTATED)}}}/")
    return "fiper_ros." + ".".join(path.with_suffix("").parts)


def _in_selection(key: str, modules: list[str]) -> bool:
    """Whether mutant ``key`` belongs to one of ``modules`` (all of them when none is given)."""
    return not modules or any(key.startswith(module + ".") for module in modules)


def _tests_digest() -> str:
    """SHA-256 over the paths and contents of the test files."""
    digest = hashlib.sha256()
    for path in sorted((ROOT / "test").rglob("*.py")):
        digest.update(str(path.relative_to(ROOT)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _retest_survivors_if_tests_changed() -> int:
    """Mark every surviving mutant unchecked when the tests changed since the last run.

    mutmut keeps a survivor's verdict until its function's source changes, so a test added to kill it
    would go unnoticed. An interrupted run does not test its survivors again when resumed.
    """
    from mutmut.mutation.data import SourceFileMutationData
    from mutmut.utils.file_utils import walk_mutatable_files

    digest, stamp = _tests_digest(), WORK / "tests.sha256"
    if stamp.is_file() and stamp.read_text() == digest:
        return 0
    count = 0
    for path in walk_mutatable_files():
        data = SourceFileMutationData(path=path)
        data.load()
        survivors = [k for k, code in data.exit_code_by_key.items() if code == 0]
        for key in survivors:
            data.exit_code_by_key[key] = None
        if survivors:
            data.save()
            count += len(survivors)
    stamp.write_text(digest)
    return count


def _summary(modules: list[str]) -> int:
    """Per file: mutants and verdicts; then every survivor's diff. Returns the number of survivors."""
    from mutmut.mutation.data import SourceFileMutationData
    from mutmut.mutation.diff_apply import get_diff_for_mutant
    from mutmut.stats import status_by_exit_code
    from mutmut.utils.file_utils import walk_mutatable_files

    columns = ("killed", "survived", "timeout", "no tests", "not checked")
    print(f"\n{'file':<28} {'mutants':>7} " + " ".join(f"{c:>11}" for c in columns) + f" {'other':>6}")
    survivors: list[tuple[str, Path]] = []
    for path in sorted(walk_mutatable_files()):
        data = SourceFileMutationData(path=path)
        data.load()
        statuses = {k: status_by_exit_code[code] for k, code in data.exit_code_by_key.items()
                    if _in_selection(k, modules)}
        if not statuses:
            continue
        counts = [sum(1 for s in statuses.values() if s == c) for c in columns]
        other = len(statuses) - sum(counts)
        print(f"{str(path.relative_to('fiper_ros')):<28} {len(statuses):>7} "
              + " ".join(f"{n:>11}" for n in counts) + f" {other:>6}")
        survivors += [(k, path) for k, s in sorted(statuses.items()) if s == "survived"]
    for key, path in survivors:
        print(f"\n# survived: {key}")
        print(get_diff_for_mutant(key, path=path))
    return len(survivors)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="*", help="modules under fiper_ros/fiper_ros, e.g. core/fusion.py")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="mutants tested at once")
    args = parser.parse_args(argv)
    if not os.environ.get("FIPER_ROOT"):
        raise SystemExit("mutants: source ./env.sh first (make mutants does)")
    modules = [_module_of(f) for f in args.files]
    _prepare_work_dir()
    os.chdir(WORK)
    again = _retest_survivors_if_tests_changed()
    if again:
        print(f"mutants: the tests changed: {again} surviving mutant(s) to test again")
    started = time.monotonic()
    command = ["mutmut", "run", "--max-children", str(args.jobs)] + [f"{m}.*" for m in modules]
    mutmut = subprocess.Popen(command, env={**os.environ, **SINGLE_THREADED})
    try:
        status = mutmut.wait()
    except KeyboardInterrupt:  # mutmut has the Ctrl-C too: it stops its workers, the verdicts so far are saved
        mutmut.wait()
        print("mutants: interrupted; run it again to go on", file=sys.stderr)
        return 130
    elapsed = time.monotonic() - started
    if status != 0:
        print(f"mutants: mutmut run failed (exit {status}) after {elapsed:.0f} s", file=sys.stderr)
        return status
    survived = _summary(modules)
    print(f"\nmutants: {elapsed:.0f} s; {survived} survivor(s). Inspect one: cd .mutmut && mutmut show NAME")
    return 0


if __name__ == "__main__":
    sys.exit(main())
