#!/usr/bin/env bash
# pred.sh SEED HYP [SCORE]: one-pass val/test predictions of a run with the ad-hoc hypothesis set
s="$1"; h="$2"; sc="${3:-y2x}"
R=/work/exp/s43/runs/run_scapo_cpu-laptop+epochs-5-4_s$s
cd /work/wt43 && HYP=$h SCORE=$sc PYTHONPATH=/work/wt43 OMP_NUM_THREADS=1 /work/main/.venv/bin/python /work/exp/s43/hyp_predict.py \
  predict --run $R --data /work/exp/s43/w/laptop_i150_v8_t64_s0_paper --out /work/exp/s43/pred/s${s}_${h}_${sc}${TAG:-}.npz \
  --option refine_steps=0 --no-progress
