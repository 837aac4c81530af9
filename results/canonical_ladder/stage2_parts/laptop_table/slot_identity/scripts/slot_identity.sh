#!/bin/bash
# session 41: bench/slot_identity.py on Table 1's SCAPO cells (0dc6165, /work/exp/tab39/w), both categories, from the
# clean worktree of the commit that adds the script (/work/wt41d). OUT: this folder.
set -e
export PYTHONPATH=/work/wt41d OMP_NUM_THREADS=1
OUT=${OUT:-/work/exp/s41/slot}
for cat in laptop eyeglasses; do
  D=/work/exp/tab39/w/${cat}_i150_v8_t64_s0_paper
  args=$(for f in $D/predictions_scapo_*.npz; do n=$(basename $f .npz); s=${n##*_s}; echo -n " --pred scapo-s$s=$f"; done)
  /work/main/.venv/bin/python /work/wt41d/bench/slot_identity.py --data $D $args --out $OUT/$cat
done
