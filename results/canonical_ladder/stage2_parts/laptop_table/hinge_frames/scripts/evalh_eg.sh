#!/bin/bash
# usage: evalh_eg.sh SPLIT   (session 39: session 37's cpu-eyeglasses runs B9s0-2 (cb0bf76, epochs-9-8) scored on
#   SPLIT: one-pass, +hinge-axis and +hinge-frames with the view prior (bench/hinge_rows.py, 92c5670); at the clean
#   worktree /work/wt39c, commit 0dc6165)
SPLIT=$1; WT=/work/wt39c
D=/work/exp/t37/eyeglasses_i150_v8_t64_s0_paper; X=/work/exp/s37/x; H=/work/exp/s39/h
OUT=/work/exp/s39/res; mkdir -p $OUT
export PYTHONPATH=$WT OMP_NUM_THREADS=1
cd $WT
P=(); F=()
for s in 0 1 2; do
  P+=("cpu-eyeglasses=$X/B9s$s/pred.npz" "cpu-eyeglasses+hinge-axis=$H/eg_B9s$s/pred+hinge-axis.npz"
      "cpu-eyeglasses+hinge-frames=$H/eg_B9s$s/pred+hinge-axis+hinge-frames+view-prior.npz")
  F+=(--pred "B9s$s=$X/B9s$s/pred.npz" --pred "B9s$s+hinge-axis=$H/eg_B9s$s/pred+hinge-axis.npz"
      --pred "B9s$s+hinge-frames=$H/eg_B9s$s/pred+hinge-axis+hinge-frames+view-prior.npz")
done
/work/main/.venv/bin/scapo evaluate --data $D --split $SPLIT --no-progress --out $OUT --name eyeglasses_hinge_frames_$SPLIT \
  --pred "${P[@]}" > $OUT/eval_eyeglasses_hinge_frames_$SPLIT.log 2>&1
/work/main/.venv/bin/python bench/frame_consistency.py --data $D --split $SPLIT \
  --out $OUT/eyeglasses_hinge_frames_${SPLIT}_frame_consistency "${F[@]}" >> $OUT/eval_eyeglasses_hinge_frames_$SPLIT.log 2>&1
