#!/usr/bin/env bash
# The shipped calibrations (models/<task>/calibration*) and transfer priors (models/priors), remade from the study's
# data (data/study, `make study`) by rules that read no failure of the task they calibrate (docs/results.md, "The
# shipped calibrations, chosen without their task's failures"; models/README.md), each keeping the delta it is
# calibrated at (the default --auto-promise delta: an OR of N thresholds at delta / N each, the priors ranked at
# equal promise by the rank statistic):
#   - each task's prior of FIPER's pair (RND-OE and ACE, the suite the launch files run) from the labelled test
#     rollouts of the two OTHER tasks: fiper evaluate --methods fiper --write-prior
#   - each task's calibration: fiper calibrate --auto --auto-rule transfer with that prior (the first entry it can
#     calibrate at delta 0.05)
#   - Sorting's second calibration, the paper's operator and threshold (AND, CP constant): the windows from a prior
#     of those configurations alone, learned on the other two tasks
#   - the default prior of `fiper calibrate --auto --auto-rule transfer` (every method, all three tasks), and the one
#     it reads with --auto-promise entry (each entry at its own promise, by the mean statistic)
# Deterministic (seeds 0-1 for the priors, the calibrations' seed 0); about 20 min on 2 cores, the scores cached.
#   bash tools/ship_calibrations.sh            (from the repository, after `source ./env.sh`)
set -euo pipefail
cd "$(dirname "$0")/.."
study=data/study
urdf=sim_bridge/sim_bridge/assets/panda/urdf/panda.urdf
declare -A DATA=([sorting]=sorting [stacking]=stacking [push_t]=pusht)
sweep=(--seeds 0-1 --protocol paper --shape-folds 5 --no-plots --urdf "$urdf" --control-dt 0.1 --quiet)
others() {  # --data of every task but $1
  local t
  for t in sorting stacking push_t; do [ "$t" = "$1" ] || printf -- '--data\n%s=%s/%s\n' "$t" "$study" "${DATA[$t]}"; done
}
for held in sorting stacking push_t; do
  mapfile -t data < <(others "$held")
  fiper evaluate "${data[@]}" "${sweep[@]}" --methods fiper --out "runs/ship/fiper-pair-without-$held" \
    --prior-top 400 --write-prior "models/priors/fiper-pair-without-$held.yaml"
done
mapfile -t data < <(others sorting)
fiper evaluate "${data[@]}" "${sweep[@]}" --methods fiper --combines and --thresholds cp_constant --no-default-combos \
  --out runs/ship/fiper-and-cp-constant-without-sorting --prior-top 400 \
  --write-prior models/priors/fiper-and-cp-constant-without-sorting.yaml
fiper evaluate --data sorting=$study/sorting --data stacking=$study/stacking --data push_t=$study/pusht "${sweep[@]}" \
  --out runs/ship/three-tasks --write-prior models/priors/sim-three-tasks.yaml
fiper evaluate --data sorting=$study/sorting --data stacking=$study/stacking --data push_t=$study/pusht "${sweep[@]}" \
  --auto-promise entry --out runs/ship/three-tasks-entry --write-prior models/priors/sim-three-tasks-entry.yaml
auto=(--auto --auto-rule transfer --force)
fiper calibrate $study/sorting/calibration "${auto[@]}" --auto-prior models/priors/fiper-pair-without-sorting.yaml \
  -o models/sorting/calibration
fiper calibrate $study/sorting/calibration "${auto[@]}" \
  --auto-prior models/priors/fiper-and-cp-constant-without-sorting.yaml -o models/sorting/calibration_cp_constant
fiper calibrate $study/stacking/calibration "${auto[@]}" --auto-prior models/priors/fiper-pair-without-stacking.yaml \
  --urdf "$urdf" --control-dt 0.1 -o models/stacking/calibration
fiper calibrate $study/pusht/calibration "${auto[@]}" --auto-prior models/priors/fiper-pair-without-push_t.yaml \
  -o models/pusht/calibration
