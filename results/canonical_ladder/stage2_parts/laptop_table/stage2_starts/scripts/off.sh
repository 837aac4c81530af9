#!/usr/bin/env bash
# off.sh SEED: one-pass predictions (every split) of the seed's cpu-laptop run with stage2_starts off, from /work/wt43b
s="$1"
cd /work/wt43b
PYTHONPATH=/work/wt43b OMP_NUM_THREADS=1 /work/main/.venv/bin/scapo predict --run /work/exp/s43/runs/run_scapo_cpu-laptop+epochs-5-4_s$s \
  --data /work/exp/s43/w/laptop_i150_v8_t64_s0_paper --out /work/exp/s43/full/predictions_s${s}_off.npz \
  --option refine_steps=0 --option stage2_starts=off --no-progress
