# Environment of the fiper-ros workspace. Source it from bash: `. ./env.sh`
# Sets the venv, the ament / library paths of the ROS 2 wheels and of our colcon install, and keeps
# DDS on this machine: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a ROS_DOMAIN_ID of this checkout
# (set ROS_DOMAIN_ID yourself to join another domain; tests and demos pick their own per run).

_fiper_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
if [ ! -x "$_fiper_root/.venv/bin/python" ] || [ ! -f "$_fiper_root/install/local_setup.sh" ]; then
  echo "fiper-ros: the workspace is not set up yet in $_fiper_root." >&2
  echo "fiper-ros: run 'make setup' there (or 'make test' / 'make demo', which set up first)." >&2
  unset _fiper_root
  return 1 2>/dev/null || exit 1
fi

export FIPER_ROOT="$_fiper_root"
export VIRTUAL_ENV="$FIPER_ROOT/.venv"
case ":$PATH:" in *":$VIRTUAL_ENV/bin:"*) ;; *) export PATH="$VIRTUAL_ENV/bin:$FIPER_ROOT/bin:$PATH" ;; esac
case ":${AMENT_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *) export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;; esac
case ":${CMAKE_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *) export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}" ;; esac
for _fiper_lib in "$VIRTUAL_ENV/lib" "$VIRTUAL_ENV"/lib/python3.11/site-packages/ros_*.libs; do
  case ":${LD_LIBRARY_PATH:-}:" in *":$_fiper_lib:"*) ;; *) export LD_LIBRARY_PATH="$_fiper_lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" ;; esac
done
# colcon's script reads unset variables: relax `set -u` of a calling script while it runs.
case $- in *u*) _fiper_nounset=1; set +u ;; *) _fiper_nounset= ;; esac
# shellcheck disable=SC1091
COLCON_CURRENT_PREFIX="$FIPER_ROOT/install" . "$FIPER_ROOT/install/local_setup.sh"
[ -n "$_fiper_nounset" ] && set -u

# The network rule: DDS discovery stays on loopback, in a domain of our own.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
if [ -z "${ROS_DOMAIN_ID:-}" ]; then
  ROS_DOMAIN_ID=$(( $(printf '%s' "$FIPER_ROOT" | cksum | cut -d' ' -f1) % 100 + 1 ))
  export ROS_DOMAIN_ID
fi
# Headless MuJoCo rendering through EGL (Mesa llvmpipe on machines without a GPU).
export MUJOCO_GL="${MUJOCO_GL:-egl}"
export PYOPENGL_PLATFORM="${PYOPENGL_PLATFORM:-egl}"
unset _fiper_root _fiper_lib _fiper_nounset
