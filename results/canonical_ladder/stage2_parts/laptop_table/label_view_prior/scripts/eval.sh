#!/bin/bash
# session 41: the label_view_prior runs beside Table 1's own SCAPO laptop cells (0dc6165, the same schedule and seeds),
# one-pass, scored on SPLIT (val: the choice), with frame consistency and the slot identity on the training split;
# from the clean worktree of e1dbf2f (/work/wt41d). usage: eval.sh SPLIT; OUT: this folder
set -e
split=$1
export PYTHONPATH=/work/wt41d OMP_NUM_THREADS=1
P=/work/main/.venv/bin/python
S=/work/main/.venv/bin/scapo
D=/work/exp/tab39/w/laptop_i150_v8_t64_s0_paper
W=/work/exp/s41/lvp
OUT=${OUT:-$W/out}
lvp=$(for s in 0 1 2; do echo -n " scapo+label-view-prior=$W/predictions_scapo+lvp_s$s.npz"; done)
$S evaluate --data $D --pred $D/predictions_scapo_cpu-laptop+epochs-5-4_s*.npz $lvp \
  --split $split --out $OUT --name laptop_label_view_prior_$split --no-progress
args=$(for s in 0 1 2; do echo -n " --pred scapo-s$s=$D/predictions_scapo_cpu-laptop+epochs-5-4_s$s.npz"; done; \
       for s in 0 1 2; do echo -n " --pred scapo+label-view-prior-s$s=$W/predictions_scapo+lvp_s$s.npz"; done)
$P /work/wt41d/bench/frame_consistency.py --data $D $args --split $split --out $OUT/laptop_label_view_prior_${split}_frame_consistency
[ "$split" != val ] || $P /work/wt41d/bench/slot_identity.py --data $D $args --out $OUT/laptop_label_view_prior_slot_identity
