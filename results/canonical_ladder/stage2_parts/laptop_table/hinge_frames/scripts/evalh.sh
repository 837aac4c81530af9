#!/bin/bash
# usage: evalh.sh SPLIT [eyeglasses]   (session 39, at the clean worktree /work/wt39c, commit 0dc6165)
#   laptop (default): session 38's cpu (LB) and cpu-laptop (LR) runs scored on SPLIT: one-pass, +slot-auto (frame
#   consistency only: nothing else changes), and for cpu-laptop +hinge-axis and +hinge-frames with the view prior
#   (hinge.sh); eyeglasses: session 37's cpu-eyeglasses runs B9s0-2 (cb0bf76, epochs-9-8): one-pass, +hinge-axis and
#   +hinge-frames with the view prior (hinge.sh NAME eyeglasses).
SPLIT=$1; WT=/work/wt39c
H=/work/exp/s39/h; SL=/work/exp/s39/slot
OUT=/work/exp/s39/res; mkdir -p $OUT
export PYTHONPATH=$WT OMP_NUM_THREADS=1
cd $WT
P=(); F=()
if [ "${2:-laptop}" = eyeglasses ]; then
  NAME=eyeglasses_hinge_frames; D=/work/exp/t37/eyeglasses_i150_v8_t64_s0_paper; X=/work/exp/s37/x
  for s in 0 1 2; do
    P+=("cpu-eyeglasses=$X/B9s$s/pred.npz" "cpu-eyeglasses+hinge-axis=$H/eg_B9s$s/pred+hinge-axis.npz"
        "cpu-eyeglasses+hinge-frames=$H/eg_B9s$s/pred+hinge-axis+hinge-frames+view-prior.npz")
    F+=(--pred "B9s$s=$X/B9s$s/pred.npz" --pred "B9s$s+hinge-axis=$H/eg_B9s$s/pred+hinge-axis.npz"
        --pred "B9s$s+hinge-frames=$H/eg_B9s$s/pred+hinge-axis+hinge-frames+view-prior.npz")
  done
else
  NAME=laptop_hinge_frames; D=/work/exp/t38/laptop_i150_v8_t64_s0_paper; X=/work/exp/s38/x
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
fi
/work/main/.venv/bin/scapo evaluate --data $D --split $SPLIT --no-progress --out $OUT --name ${NAME}_$SPLIT \
  --pred "${P[@]}" > $OUT/eval_${NAME}_$SPLIT.log 2>&1
/work/main/.venv/bin/python bench/frame_consistency.py --data $D --split $SPLIT \
  --out $OUT/${NAME}_${SPLIT}_frame_consistency "${F[@]}" >> $OUT/eval_${NAME}_$SPLIT.log 2>&1
