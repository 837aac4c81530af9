#!/bin/bash
# session 40: bench/table1_paper_two_categories.sh FRAMES=1's steps one file at a time (the same outputs; a file
# already written is kept), at 0dc6165 from /work/wt39t. usage: frames_all.sh CATEGORY
set -e
cat=$1
cd /work/exp/tab39/w
export PYTHONPATH=/work/wt39t OMP_NUM_THREADS=1
P=/work/main/.venv/bin/python
S=/work/main/.venv/bin/scapo
data=${cat}_i150_v8_t64_s0_paper
dst=hinge_frames/$cat
for f in hinge_axis/$cat/*.npz; do
  n=$(basename $f .npz)
  [ -f $dst/$n+hinge-frames+view-prior.npz ] || $P /work/wt39t/bench/hinge_rows.py --frames --view-prior \
    --skip-without-train --data $data --pred $f --out-dir $dst
done
for run in $data/run_npcs_*; do
  name=$(basename $run)
  pred="$dst/predictions_${name#run_}+hinge-axis+hinge-frames+view-prior.npz"
  [ -f "$pred" ] || $S predict --run "$run" --data $data --out "$pred" --no-progress --option hinge=true \
    --option hinge_axis=true --option hinge_frames=true --option hinge_view_prior=true
done
echo done > /work/exp/s40/frames_$cat.status
