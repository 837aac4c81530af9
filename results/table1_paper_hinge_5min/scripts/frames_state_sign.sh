#!/bin/bash
# session 41: the FRAMES=1 steps of bench/table1_paper_two_categories.sh again for one category, at 2eb3181 (the view
# prior's exchanged views negate the base joint's state) from its clean worktree /work/wt41b, on the hinge-axis files
# of session 40 (0dc6165; the hinge and hinge-axis steps are unchanged between the two commits), into
# /work/exp/s41/hf; then the FRAMES=1 evaluate call and bench/frame_consistency.py (as scripts/eval_hinge.sh).
# usage: frames_state_sign.sh CATEGORY
set -e
cat=$1
cd /work/exp/s41/hf   # holds links to session 40's dataset and hinge_axis/ (/work/exp/tab39/w)
export PYTHONPATH=/work/wt41b OMP_NUM_THREADS=1
P=/work/main/.venv/bin/python
S=/work/main/.venv/bin/scapo
data=${cat}_i150_v8_t64_s0_paper
dst=hinge_frames/$cat
for f in hinge_axis/$cat/*.npz; do
  n=$(basename $f .npz)
  [ -f $dst/$n+hinge-frames+view-prior.npz ] || $P /work/wt41b/bench/hinge_rows.py --frames --view-prior \
    --skip-without-train --data $data --pred $f --out-dir $dst
done
for run in $data/run_npcs_*; do
  name=$(basename $run)
  pred="$dst/predictions_${name#run_}+hinge-axis+hinge-frames+view-prior.npz"
  [ -f "$pred" ] || $S predict --run "$run" --data $data --out "$pred" --no-progress --option hinge=true \
    --option hinge_axis=true --option hinge_frames=true --option hinge_view_prior=true
done
out=hinge_out
$S evaluate --data $data --pred $data/predictions_*.npz hinge_axis/$cat/*.npz $dst/*.npz --split test \
  --out $out --name ${cat}_frames --no-progress
args=$(for f in $data/predictions_*.npz hinge_axis/$cat/*.npz $dst/*.npz; do
  n=$(basename $f .npz); n=${n#predictions_}
  label=$(echo "$n" | sed -E 's/^([a-z-]+)_[^_]*_s([0-9]+)(.*)$/\1\3-s\2/')
  echo -n " --pred $label=$PWD/$f"; done)
$P /work/wt41b/bench/frame_consistency.py --data $PWD/$data $args --split test --out $out/${cat}_frames_consistency
echo done > /work/exp/s41/frames_$cat.status
