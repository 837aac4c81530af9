#!/usr/bin/env bash
# Table 1 in the paper's viewpoints on laptop and eyeglasses (issue 52): every method (ICP, NPCS-style, EAP-style,
# OP-Align-style, SCAPO), 150 instances (30 test) x 8 views, 64 views per training instance, training seeds 0,1,2,
# one-pass rows only, every training run at the equal budget of BUDGET core-minutes of one CPU core (epochs from each
# method's clouds/s measured once per dataset: `scapo bench table1 --budget-minutes`). On a 2-core machine: the
# datasets and the speeds first (one method at a time, one torch thread; about 35 minutes for the eight; run nothing
# else meanwhile, since the epochs follow the speeds), then two chains side by side (one torch thread each), then the
# table from every finished cell. Each method trains with its per-category preset
# where it registers one (SCAPO: cpu-eyeglasses and cpu-laptop, scapo.models.presets.EYEGLASSES_PARTS). Resumable; run
# it from a clean worktree of the commit the table records (SCAPO= its scapo, PYTHONPATH= the worktree).
#   BUDGET=5 WORK=bench_work/table1_paper bash bench/table1_paper_two_categories.sh
#   FINISH=1 bash bench/table1_paper_two_categories.sh        # the table of the finished cells, into results/
#   PARTS="scapo/principal" ...                               # extra rows (bench table1 --part), in chain A
#   OPTION_ROWS="scapo:base-auto:base_frame=principal,base_slot=auto" ...  # rows of the same runs predicted with
#                                                             # options (bench table1 --option-row; no training)
#   HINGE=1 bash bench/table1_paper_two_categories.sh         # after FINISH: every cell's predictions with and without
#                                                             # the hinge re-split, and with its axes too (bench/diagnostics/hinge_rows.py
#                                                             # [--axis]), scored on test
#                                                             # into results/table1_paper_hinge_<BUDGET>min/<category>.*
#   FRAMES=1 bash bench/table1_paper_two_categories.sh        # after HINGE: the hinge-axis predictions with the part
#                                                             # rotations from the hinges and the view prior
#                                                             # (bench/diagnostics/hinge_rows.py --frames --view-prior; NPCS-style
#                                                             # predicted again with the options, ICP has no training
#                                                             # split to fit on), scored on test beside the one-pass
#                                                             # and hinge-axis rows into .../<category>_frames.*
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
scapo="${SCAPO:-.venv/bin/scapo}"
work="${WORK:-bench_work/table1_paper}"
common=(bench table1 --viewpoints paper --categories laptop,eyeglasses --seeds 0,1,2 --budget-minutes "${BUDGET:-5}"
        --no-refine-rows --work "$work" --name table1_paper_two_categories --no-progress)
parts=()
for p in ${PARTS:-}; do parts+=(--part "$p"); done
for r in ${OPTION_ROWS:-}; do parts+=(--option-row "$r"); done
if [ -n "${HINGE:-}" ]; then
  out="${OUT:-results}/table1_paper_hinge_${BUDGET:-5}min"
  for data in "$work"/*_paper; do
    cat="$(basename "$data")"; cat="${cat%%_*}"
    preds=("$data"/predictions_*.npz)
    "${PYTHON:-.venv/bin/python}" bench/diagnostics/hinge_rows.py --data "$data" --pred "${preds[@]}" --out-dir "$work/hinge/$cat"
    "${PYTHON:-.venv/bin/python}" bench/diagnostics/hinge_rows.py --axis --data "$data" --pred "${preds[@]}" \
      --out-dir "$work/hinge_axis/$cat"
    "$scapo" evaluate --data "$data" --pred "${preds[@]}" "$work/hinge/$cat"/*.npz "$work/hinge_axis/$cat"/*.npz \
      --split test --out "$out" --name "$cat" --no-progress
  done
  exit 0
fi
if [ -n "${FRAMES:-}" ]; then
  out="${OUT:-results}/table1_paper_hinge_${BUDGET:-5}min"
  for data in "$work"/*_paper; do
    cat="$(basename "$data")"; cat="${cat%%_*}"
    dst="$work/hinge_frames/$cat"
    "${PYTHON:-.venv/bin/python}" bench/diagnostics/hinge_rows.py --frames --view-prior --skip-without-train --data "$data" \
      --pred "$work/hinge_axis/$cat"/*.npz --out-dir "$dst"
    for run in "$data"/run_npcs_*; do
      name="$(basename "$run")"
      pred="$dst/predictions_${name#run_}+hinge-axis+hinge-frames+view-prior.npz"
      [ -f "$pred" ] || "$scapo" predict --run "$run" --data "$data" --out "$pred" --no-progress --option hinge=true \
        --option hinge_axis=true --option hinge_frames=true --option hinge_view_prior=true
    done
    "$scapo" evaluate --data "$data" --pred "$data"/predictions_*.npz "$work/hinge_axis/$cat"/*.npz "$dst"/*.npz \
      --split test --out "$out" --name "${cat}_frames" --no-progress
  done
  exit 0
fi
if [ -n "${FINISH:-}" ]; then
  exec "$scapo" "${common[@]}" "${parts[@]}" --finished-only --out "${OUT:-results}"
fi
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --data-only --workers 2
mkdir -p "$work"
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --out "$work/out_a" --methods "${CHAIN_A:-scapo,op-align}" "${parts[@]}" \
  > "$work/chain_a.log" 2>&1 &
a=$!
# each chain checks the datasets under their folders' lock first: start chain B once chain A has (a fixed pause lost
# that race on a loaded machine in session 39, and chain A stopped at its start)
until grep -q "datasets ready" "$work/chain_a.log" 2>/dev/null || ! kill -0 $a 2>/dev/null; do sleep 2; done
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --out "$work/out_b" --methods "${CHAIN_B:-npcs,eap,icp}" \
  > "$work/chain_b.log" 2>&1 &
b=$!
wait $a $b
"$scapo" "${common[@]}" "${parts[@]}" --finished-only --out "${OUT:-results}"
