#!/bin/bash
# usage: evalh.sh SPLIT   (session 39: the cpu and cpu-laptop runs of session 38 scored on SPLIT: one-pass, +slot-auto
#   (frame consistency only: nothing else changes), and for cpu-laptop +hinge-axis and +hinge-frames with the view
#   prior (bench/hinge_rows.py); at the clean worktree /work/wt39c, commit 0dc6165)
SPLIT=$1; WT=/work/wt39c
D=/work/exp/t38/laptop_i150_v8_t64_s0_paper; X=/work/exp/s38/x; H=/work/exp/s39/h; SL=/work/exp/s39/slot
OUT=/work/exp/s39/res; mkdir -p $OUT
export PYTHONPATH=$WT OMP_NUM_THREADS=1
cd $WT
P=(); F=()
for s in 0 1 2; do  # cpu: one-pass and +slot-auto only (its hinge rows are Table 1's, fedfedd)
  P+=("cpu=$X/LB$s/pred.npz")
  F+=(--pred "LB$s=$X/LB$s/pred.npz" --pred "LB$s+slot-auto=$SL/LB$s/pred.npz")
done
for s in 0 1 2; do
  P+=("cpu-laptop=$X/LR$s/pred.npz" "cpu-laptop+hinge-axis=$H/LR$s/pred+hinge-axis.npz"
      "cpu-laptop+hinge-frames=$H/LR$s/pred+hinge-axis+hinge-frames+view-prior.npz")
  F+=(--pred "LR$s=$X/LR$s/pred.npz" --pred "LR$s+slot-auto=$SL/LR$s/pred.npz"
      --pred "LR$s+hinge-axis=$H/LR$s/pred+hinge-axis.npz"
      --pred "LR$s+hinge-frames=$H/LR$s/pred+hinge-axis+hinge-frames+view-prior.npz")
done
/work/main/.venv/bin/scapo evaluate --data $D --split $SPLIT --no-progress --out $OUT --name laptop_hinge_frames_$SPLIT \
  --pred "${P[@]}" > $OUT/eval_laptop_hinge_frames_$SPLIT.log 2>&1
/work/main/.venv/bin/python bench/frame_consistency.py --data $D --split $SPLIT \
  --out $OUT/laptop_hinge_frames_${SPLIT}_frame_consistency "${F[@]}" >> $OUT/eval_laptop_hinge_frames_$SPLIT.log 2>&1
