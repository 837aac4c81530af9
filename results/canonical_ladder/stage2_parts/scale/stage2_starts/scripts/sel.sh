#!/usr/bin/env bash
# sel.sh SPLIT: the eyeglasses' stage2_starts arms (off, D2, O) of the seeds' ad-hoc predictions (pred.sh):
# bench/frame_by_state.py per seed, and sub_evaluate.py (scapo evaluate with the alignment fitted on the same
# training subsample) over the seeds, from the clean worktree /work/wt44 (1046751)
set -e
SPLIT=$1
E=/work/exp/s43/w/eyeglasses_i150_v8_t64_s0_paper
P=/work/exp/s44/pred
OUT=/work/exp/s44/sel
cd /work/wt44
export PYTHONPATH=/work/wt44 OMP_NUM_THREADS=1
off=(); d2=(); on=()
for s in ${SEEDS:-0 1 2}; do
  /work/main/.venv/bin/python bench/frame_by_state.py --data $E --split $SPLIT --pred off=$P/s${s}_off.npz \
    --pred D2=$P/s${s}_D2.npz --pred O=$P/s${s}_O.npz --out $OUT/${SPLIT}_frame_by_state_s$s
  off+=(off=$P/s${s}_off.npz); d2+=(D2=$P/s${s}_D2.npz); on+=(O=$P/s${s}_O.npz)
done
/work/main/.venv/bin/python /work/exp/s44/sub_evaluate.py evaluate --data $E --split $SPLIT --no-progress --out $OUT \
  --name stage2_starts_eyeglasses_${SPLIT}_adhoc --pred "${off[@]}" "${d2[@]}" "${on[@]}"
