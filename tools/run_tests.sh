#!/usr/bin/env bash
# Run the whole test suite inside the workspace environment (make test calls this after set-up).
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source ./env.sh || exit 2
# Two worker processes, each taking whole test files (a file's module fixtures stay in one process): the tests
# wait on DDS and child processes for much of their time, so two share the two cores of our machine
# (docs/testing.md, "How make test runs"). FIPER_TEST_WORKERS=0 runs them in this process, one after another.
python -m pytest -n "${FIPER_TEST_WORKERS:-2}" --dist loadfile "$@"
status=$?
if [ "$status" -eq 5 ]; then
  echo "run_tests: pytest collected no tests: that is a failure here" >&2
  exit 1
fi
exit "$status"
