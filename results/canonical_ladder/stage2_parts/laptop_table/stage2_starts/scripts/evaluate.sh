#!/usr/bin/env bash
# evaluate.sh SPLIT: scapo evaluate (paired bootstrap) and bench/frame_by_state.py of the seeds' one-pass predictions
# with stage2_starts off (scripts/off.sh, at 55b5e78) and O (the cpu-laptop preset's; scripts/full.sh, at 573697a,
# whose first output name was _none: renamed _O), from the clean worktree /work/wt43b (55b5e78). SEEDS="0 1 2" by
# default (session 44: seed 2's O prediction by scripts/full_s2.sh; session 43 ran it with SEEDS="0 1")
set -e
SPLIT=$1
D=/work/exp/s43/w/laptop_i150_v8_t64_s0_paper
P=/work/exp/s43/full
OUT=/work/exp/s43/res
mkdir -p $OUT
cd /work/wt43b
export PYTHONPATH=/work/wt43b OMP_NUM_THREADS=1
off=(); on=(); fbs=()
for s in ${SEEDS:-0 1 2}; do
  off+=(off=$P/predictions_s${s}_off.npz); on+=(O=$P/predictions_s${s}_O.npz)
  fbs+=(--pred off-s$s=$P/predictions_s${s}_off.npz --pred O-s$s=$P/predictions_s${s}_O.npz)
done
/work/main/.venv/bin/scapo evaluate --data $D --split $SPLIT --no-progress --out $OUT --name stage2_starts_$SPLIT \
  --pred "${off[@]}" "${on[@]}"
/work/main/.venv/bin/python bench/frame_by_state.py --data $D --split $SPLIT --out $OUT/stage2_starts_${SPLIT}_frame_by_state \
  "${fbs[@]}"
