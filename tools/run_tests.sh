#!/usr/bin/env bash
# Run the whole test suite inside the workspace environment (make test calls this after set-up).
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source ./env.sh || exit 2
python -m pytest "$@"
status=$?
if [ "$status" -eq 5 ]; then
  echo "run_tests: pytest collected no tests: that is a failure here" >&2
  exit 1
fi
exit "$status"
