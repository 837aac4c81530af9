#!/bin/bash
# session 41: SCAPO laptop at the table's schedule (cpu-laptop/epochs-5-4, 900 steps) with label_view_prior=true,
# on Table 1's laptop data (0dc6165's dataset), one seed; one-pass predictions of every split. From the clean worktree
# of ef13f17 (/work/wt41c). usage: run.sh SEED   (the three seeds ran side by side with two compute-curve chains)
set -e
s=$1
export PYTHONPATH=/work/wt41c OMP_NUM_THREADS=1
S=/work/main/.venv/bin/scapo
D=/work/exp/tab39/w/laptop_i150_v8_t64_s0_paper
W=/work/exp/s41/lvp
$S train --method scapo --data $D --preset cpu-laptop/epochs-5-4 --seed $s --set label_view_prior=true \
  --out $W/run_lvp_s$s --no-progress
[ -f $W/predictions_scapo+lvp_s$s.npz ] || $S predict --run $W/run_lvp_s$s --data $D --out $W/predictions_scapo+lvp_s$s.npz \
  --option refine_steps=0 --no-progress
echo done > $W/s$s.status
