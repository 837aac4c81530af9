#!/usr/bin/env bash
# eval_eye.sh SPLIT: scapo evaluate (paired bootstrap) and bench/frame_by_state.py of the seeds' full one-pass
# eyeglasses predictions (full_eye.sh) with stage2_starts off and D2, from the clean worktree /work/wt44 (1046751)
set -e
SPLIT=$1
E=/work/exp/s43/w/eyeglasses_i150_v8_t64_s0_paper
P=/work/exp/s44/full
OUT=/work/exp/s44/res
mkdir -p $OUT
cd /work/wt44
export PYTHONPATH=/work/wt44 OMP_NUM_THREADS=1
off=(); on=(); fbs=()
for s in ${SEEDS:-0 1 2}; do
  off+=(off=$P/eye_s${s}_off.npz); on+=(D2=$P/eye_s${s}_D2.npz)
  fbs+=(--pred off-s$s=$P/eye_s${s}_off.npz --pred D2-s$s=$P/eye_s${s}_D2.npz)
done
/work/main/.venv/bin/scapo evaluate --data $E --split $SPLIT --no-progress --out $OUT --name stage2_starts_eyeglasses_$SPLIT \
  --pred "${off[@]}" "${on[@]}"
/work/main/.venv/bin/python bench/frame_by_state.py --data $E --split $SPLIT \
  --out $OUT/stage2_starts_eyeglasses_${SPLIT}_frame_by_state "${fbs[@]}"
