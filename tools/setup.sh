#!/usr/bin/env bash
# One-command set-up of the fiper-ros workspace on a fresh machine; idempotent and fast when nothing
# changed. Steps: Debian packages -> venv with pinned wheels -> CMake path fix -> colcon build.
# Each step keeps a stamp (a hash of its inputs) and is skipped when the stamp matches.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
STAMPS="$VENV/.fiper-stamps"
LOCK="$ROOT/requirements.lock"
# Debian packages: compilers and cmake for the interface package, EGL/Mesa for headless MuJoCo
# rendering, tcpdump for the test that proves DDS traffic stays on loopback.
APT_PACKAGES=(cmake make g++ libegl1 libegl-mesa0 libgl1-mesa-dri libglvnd0 tcpdump)

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }
hash_of() { cat "$@" | sha256sum | cut -d' ' -f1; }
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; printf '%s' "$2" > "$STAMPS/$1"; }

t0=$SECONDS

# 1. Debian packages (installed only when missing).
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
  [ "$(id -u)" -eq 0 ] || die "missing Debian packages: ${missing[*]} (run as root or: sudo apt-get install ${missing[*]})"
  say "installing Debian packages: ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# 2. Python 3.11 venv with the exact pinned wheels (the ROS 2 wheels are cp311-only).
PYTHON="${FIPER_PYTHON:-}"
if [ -z "$PYTHON" ]; then
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      PYTHON="$(command -v "$cand")"; break
    fi
  done
fi
[ -n "$PYTHON" ] || die "Python 3.11 not found (the ROS 2 Jazzy wheels are built for CPython 3.11); set FIPER_PYTHON"
if [ ! -x "$VENV/bin/python" ]; then
  say "creating venv $VENV with $PYTHON"
  "$PYTHON" -m venv "$VENV"
fi
lock_hash="$(hash_of "$LOCK")"
if ! stamp_ok pip "$lock_hash"; then
  say "installing pinned wheels from requirements.lock (first time: several minutes, ~3 GB download)"
  # The lock pins every wheel, so no dependency resolution is needed (--no-deps). It leaves out
  # triton, the GPU kernel compiler the CUDA torch wheel requires: useless without a GPU (1 GB), and
  # importing it segfaults a process that also renders with Mesa EGL and runs rclpy.
  "$VENV/bin/python" -m pip install --quiet --no-input --no-deps -r "$LOCK"
  "$VENV/bin/python" -m pip uninstall --quiet --yes triton 2>/dev/null || true
  problems="$("$VENV/bin/python" -m pip check 2>&1 | grep -v -E '^torch [^ ]+ requires triton, which is not installed.$' || true)"
  [ "$problems" = "No broken requirements found." ] || [ -z "$problems" ] || die "pip check failed: $problems"
  rm -f "$STAMPS/cmake-fix"
  stamp_set pip "$lock_hash"
fi

# 3. CMake path fix for the message wheels (idempotent; redone after any reinstall).
if ! stamp_ok cmake-fix "$lock_hash"; then
  "$VENV/bin/python" "$ROOT/tools/fix_cmake_paths.py" "$VENV"
  stamp_set cmake-fix "$lock_hash"
fi

# 4. colcon build of fiper_msgs, fiper_ros and sim_bridge, driven by colcon.meta.
build_inputs=("$ROOT/colcon.meta" "$LOCK" "$ROOT/tools/setup.sh")
while IFS= read -r f; do build_inputs+=("$f"); done < <(
  cd "$ROOT" && find fiper_msgs fiper_ros sim_bridge -maxdepth 2 \
    \( -name package.xml -o -name CMakeLists.txt -o -name setup.py -o -name setup.cfg -o -name '*.msg' \
       -o -name '*.srv' -o -path '*/config/*.yaml' -o -path '*/launch/*.launch.*' \) -type f | sort | sed "s|^|$ROOT/|")
# The shipped models are installed with fiper_ros (fiper_ros/models links to models/): a new file needs a build.
while IFS= read -r f; do build_inputs+=("$f"); done < <(cd "$ROOT" && find models -type f | sort | sed "s|^|$ROOT/|")
build_hash="$(hash_of "${build_inputs[@]}")"
# The build's stamp lives in this checkout's install space, not in the venv: worktrees that share one venv
# each build their own install/ (a shared stamp once left a checkout's build stale).
build_stamp="$ROOT/install/.fiper-build-stamp"
if [ ! -f "$build_stamp" ] || [ "$(cat "$build_stamp")" != "$build_hash" ] || [ ! -f "$ROOT/install/local_setup.sh" ]; then
  say "colcon build"
  mkdir -p "$ROOT/log"
  # A symlink build keeps links to sources that were removed since (a deleted config file): drop them, or
  # setup.py's data_files step fails on them.
  find "$ROOT/build" "$ROOT/install" -xtype l -delete 2>/dev/null || true
  (
    cd "$ROOT"
    export VIRTUAL_ENV="$VENV" PATH="$VENV/bin:$PATH"
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    LD_LIBRARY_PATH="$VENV/lib"
    for d in "$VENV"/lib/python3.11/site-packages/ros_*.libs; do LD_LIBRARY_PATH="$LD_LIBRARY_PATH:$d"; done
    export LD_LIBRARY_PATH
    "$VENV/bin/colcon" --log-base log build --symlink-install --metas colcon.meta --base-paths fiper_msgs fiper_ros sim_bridge \
      --event-handlers console_cohesion+ summary+ > "$ROOT/log/colcon-build.txt" 2>&1 \
      || { tail -n 60 "$ROOT/log/colcon-build.txt" >&2; die "colcon build failed (full log: log/colcon-build.txt)"; }
  )
  printf '%s' "$build_hash" > "$build_stamp"
fi

say "ready in $((SECONDS - t0)) s: source ./env.sh to use the workspace"
