#!/bin/bash
# session 40: frames_all.sh eyeglasses' NPCS-style predictions, ahead (the same command and output names)
cd /work/exp/tab39/w
export PYTHONPATH=/work/wt39t OMP_NUM_THREADS=1
data=eyeglasses_i150_v8_t64_s0_paper; dst=hinge_frames/eyeglasses; mkdir -p $dst
for run in $data/run_npcs_*; do
  name=$(basename $run)
  pred="$dst/predictions_${name#run_}+hinge-axis+hinge-frames+view-prior.npz"
  [ -f "$pred" ] || /work/main/.venv/bin/scapo predict --run "$run" --data $data --out "$pred" --no-progress \
    --option hinge=true --option hinge_axis=true --option hinge_frames=true --option hinge_view_prior=true
done
