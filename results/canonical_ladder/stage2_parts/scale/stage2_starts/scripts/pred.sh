#!/usr/bin/env bash
# pred.sh SEED SET...: one-pass predictions (val/test, training split every 8th view) of the seed's cpu-eyeglasses run
# with --option stage2_starts=SET, from the clean worktree /work/wt44 (1046751)
s="$1"; shift
R=/work/exp/s44/runs/run_scapo_cpu-eyeglasses+epochs-6-5_s$s
mkdir -p /work/exp/s44/pred
cd /work/wt44
for h in "$@"; do
  o=/work/exp/s44/pred/s${s}_$h.npz
  [ -f $o ] && continue
  PYTHONPATH=/work/wt44 OMP_NUM_THREADS=1 /work/main/.venv/bin/python /work/exp/s44/sub_predict.py predict --run $R \
    --data /work/exp/s43/w/eyeglasses_i150_v8_t64_s0_paper --out $o --option refine_steps=0 --option stage2_starts=$h --no-progress
done
