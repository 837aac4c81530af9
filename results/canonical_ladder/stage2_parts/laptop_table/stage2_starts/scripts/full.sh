#!/usr/bin/env bash
# full.sh SEED: one-pass predictions (every split) of the seed's cpu-laptop run, without and with stage2_starts (the
# preset's O), from the clean worktree of 573697a
s="$1"
R=/work/exp/s43/runs/run_scapo_cpu-laptop+epochs-5-4_s$s
D=/work/exp/s43/w/laptop_i150_v8_t64_s0_paper
cd /work/wt43
export PYTHONPATH=/work/wt43 OMP_NUM_THREADS=1
[ -f /work/exp/s43/full/predictions_s${s}_none.npz ] || /work/main/.venv/bin/scapo predict --run $R --data $D \
  --out /work/exp/s43/full/predictions_s${s}_none.npz --option refine_steps=0 --option stage2_starts=none --no-progress
[ -f /work/exp/s43/full/predictions_s${s}_O.npz ] || /work/main/.venv/bin/scapo predict --run $R --data $D \
  --out /work/exp/s43/full/predictions_s${s}_O.npz --option refine_steps=0 --no-progress
