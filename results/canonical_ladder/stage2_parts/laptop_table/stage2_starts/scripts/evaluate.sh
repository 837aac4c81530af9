#!/usr/bin/env bash
# evaluate.sh SPLIT: scapo evaluate (paired bootstrap) and bench/frame_by_state.py of the three seeds' one-pass
# predictions with stage2_starts off and O (the cpu-laptop preset's), from the clean worktree /work/wt43b (55b5e78)
set -e
SPLIT=$1
D=/work/exp/s43/w/laptop_i150_v8_t64_s0_paper
P=/work/exp/s43/full
OUT=/work/exp/s43/res
mkdir -p $OUT
cd /work/wt43b
export PYTHONPATH=/work/wt43b OMP_NUM_THREADS=1
/work/main/.venv/bin/scapo evaluate --data $D --split $SPLIT --no-progress --out $OUT --name stage2_starts_$SPLIT \
  --pred off=$P/predictions_s0_off.npz off=$P/predictions_s1_off.npz off=$P/predictions_s2_off.npz \
         O=$P/predictions_s0_O.npz O=$P/predictions_s1_O.npz O=$P/predictions_s2_O.npz
/work/main/.venv/bin/python bench/frame_by_state.py --data $D --split $SPLIT --out $OUT/stage2_starts_${SPLIT}_frame_by_state \
  --pred off-s0=$P/predictions_s0_off.npz --pred off-s1=$P/predictions_s1_off.npz --pred off-s2=$P/predictions_s2_off.npz \
  --pred O-s0=$P/predictions_s0_O.npz --pred O-s1=$P/predictions_s1_O.npz --pred O-s2=$P/predictions_s2_O.npz
