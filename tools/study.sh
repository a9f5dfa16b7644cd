#!/usr/bin/env bash
# The FIPER-vs-baselines study on closed-loop sim rollouts (docs/results.md): `make study` or
#   bash tools/study.sh [TASK...]          (default: every task with a shipped model in models/)
# Per task: a calibration set of M = 50 successful ID rollouts (seeds 2000, 2001, ...; STUDY_EXTRA more from seed
# 3000 into data/study/<task>/calibration_extra, so M = 50 + STUDY_EXTRA), a test set of
# 50 rollouts per scenario (ID, benign and harmful OOD; seeds 1000..1049), each rollout an MCAP bag
# written by `fiper collect` under data/study/<task>/ (resumable: a rerun skips finished bags), then
# `fiper evaluate` with all seven methods and the elapsed-time baseline (split conformal calibration), 5 seeds,
# the paper's and the clean protocol into runs/study/.
# Environment: STUDY_EPISODES (50), STUDY_SEEDS (0-4), STUDY_OUT (runs/study), STUDY_JOBS (episodes at
# once, default: the number of cores; the bags are the same for any number), STUDY_EXTRA (0; 50 and 150 give the
# M = 100 and M = 200 runs of docs/results.md).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source ./env.sh
EPISODES="${STUDY_EPISODES:-50}"
EXTRA="${STUDY_EXTRA:-0}"
SEEDS="${STUDY_SEEDS:-0-4}"
OUT="${STUDY_OUT:-runs/study}"
JOBS="${STUDY_JOBS:-$(nproc)}"
if [ "$#" -gt 0 ]; then TASKS=("$@"); else
  TASKS=(); for task in sorting stacking pusht; do [ -f "models/$task/policy.yaml" ] && TASKS+=("$task"); done
fi
started=$(date +%s)
data_args=()
for task in "${TASKS[@]}"; do
  scenarios=$(python -c "from sim_bridge.scenarios import SCENARIOS; print(' '.join(SCENARIOS['$task']))")
  echo "[study] $task: calibration set (50 ID successes from seed 2000), test set ($EPISODES per scenario: $scenarios)"
  fiper collect --task "$task" --scenarios id --successes 50 --seed 2000 --split calibration --jobs "$JOBS" \
    --out "data/study/$task/calibration"
  calibration="data/study/$task/calibration"
  if [ "$EXTRA" -gt 0 ]; then
    fiper collect --task "$task" --scenarios id --successes "$EXTRA" --seed 3000 --split calibration --jobs "$JOBS" \
      --out "data/study/$task/calibration_extra"
    calibration+=",data/study/$task/calibration_extra"
  fi
  # shellcheck disable=SC2086
  fiper collect --task "$task" --scenarios $scenarios --episodes "$EPISODES" --seed 1000 --split test --jobs "$JOBS" \
    --out "data/study/$task/test"
  # the evaluation's name of the PushT task is push_t (the paper's tables)
  name="$task"; [ "$task" = pusht ] && name=push_t
  data_args+=(--data "$name=$calibration,data/study/$task/test")
done
# Stacking's actions are joint velocities: ACE maps them through the sim's Panda (10 Hz control)
fiper evaluate "${data_args[@]}" --seeds "$SEEDS" --protocol paper,clean --out "$OUT" \
  --urdf sim_bridge/sim_bridge/assets/panda/urdf/panda.urdf --control-dt 0.1
echo "[study] done in $(( $(date +%s) - started )) s: $OUT/results.md"
