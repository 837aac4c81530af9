#!/usr/bin/env bash
# full_eye.sh SET SEED...: full one-pass predictions (every split, the whole training split) of the seeds'
# cpu-eyeglasses runs with --option stage2_starts=SET, from the clean worktree /work/wt44 (1046751)
h="$1"; shift
cd /work/wt44
for s in "$@"; do
  o=/work/exp/s44/full/eye_s${s}_$h.npz
  [ -f $o ] && continue
  PYTHONPATH=/work/wt44 OMP_NUM_THREADS=1 /work/main/.venv/bin/scapo predict --run /work/exp/s44/runs/run_scapo_cpu-eyeglasses+epochs-6-5_s$s \
    --data /work/exp/s43/w/eyeglasses_i150_v8_t64_s0_paper --out $o --option refine_steps=0 --option stage2_starts=$h --no-progress
done
