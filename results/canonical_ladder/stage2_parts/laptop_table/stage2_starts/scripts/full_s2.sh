#!/usr/bin/env bash
# seed 2's one-pass prediction with the cpu-laptop preset's stage2_starts (O), every split, from the clean worktree of 573697a (the commit of seeds 0 and 1's O predictions)
s=2
R=/work/exp/s43/runs/run_scapo_cpu-laptop+epochs-5-4_s$s
D=/work/exp/s43/w/laptop_i150_v8_t64_s0_paper
cd /work/wt43
export PYTHONPATH=/work/wt43 OMP_NUM_THREADS=1
[ -f /work/exp/s43/full/predictions_s${s}_O.npz ] || /work/main/.venv/bin/scapo predict --run $R --data $D \
  --out /work/exp/s43/full/predictions_s${s}_O.npz --option refine_steps=0 --no-progress
