#!/bin/bash
# session 40: the two scapo evaluate calls of HINGE=1 and FRAMES=1 (bench/table1_paper_two_categories.sh) for one
# category, at 0dc6165, into /work/exp/tab39/w/hinge_out; then frame consistency of the frames files. usage: CATEGORY
set -e
cat=$1
cd /work/exp/tab39/w
export PYTHONPATH=/work/wt39t OMP_NUM_THREADS=1
S=/work/main/.venv/bin/scapo
data=${cat}_i150_v8_t64_s0_paper
out=hinge_out
$S evaluate --data $data --pred $data/predictions_*.npz hinge/$cat/*.npz hinge_axis/$cat/*.npz --split test --out $out \
  --name $cat --no-progress
$S evaluate --data $data --pred $data/predictions_*.npz hinge_axis/$cat/*.npz hinge_frames/$cat/*.npz --split test \
  --out $out --name ${cat}_frames --no-progress
# labels as the README's headline reads them: <method>[+steps]-s<seed> (one-pass, hinge-axis and frames rows; ICP: icp)
args=$(for f in $data/predictions_*.npz hinge_axis/$cat/*.npz hinge_frames/$cat/*.npz; do
  n=$(basename $f .npz); n=${n#predictions_}
  label=$(echo "$n" | sed -E 's/^([a-z-]+)_[^_]*_s([0-9]+)(.*)$/\1\3-s\2/')
  echo -n " --pred $label=$PWD/$f"; done)
/work/main/.venv/bin/python /work/wt39t/bench/frame_consistency.py --data $PWD/$data $args --split test \
  --out $out/${cat}_frames_consistency
echo done > /work/exp/s40/eval_$cat.status
