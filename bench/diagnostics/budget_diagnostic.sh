#!/usr/bin/env bash
# Gap attribution (issue 31): how much of SCAPO's distance to the paper's numbers is its training budget? SCAPO's
# cpu preset trained FACTOR times longer (every stage's epochs x FACTOR; all else equal: data, seed, batch,
# points) on one Table 1 dataset, predicted one-pass, and compared with that category's Table 1 cell of the same
# seed (the cpu preset's 15 minutes on one core) by bench/diagnostics/compare_predictions.py: means, medians, flip rates and
# the paired bootstrap over test instances. A diagnostic, not a table row (only SCAPO gets the longer budget).
#
#   bash bench/diagnostics/budget_diagnostic.sh     (CATEGORY=laptop FACTOR=4 SEED=0 PRESET=cpu; WORK=bench_work/table1_cpu,
#                                        the tables' work folder whose Table 1 cell is compared;
#                                        OUT=results/diagnostics/budget)
#
# Resumable: the training resumes per epoch and finished steps are skipped. Run it with the code of the Table 1
# cells (SCAPO=<their worktree>/.venv/bin/scapo and PYTHONPATH=<that worktree>, so that this run and the cell
# share a commit; the script records the commit it ran), one core and one thread (taskset, OMP_NUM_THREADS=1)
# as the cells were.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
SCAPO=${SCAPO:-.venv/bin/scapo}
PY="$(dirname "$SCAPO")/python"
WORK=${WORK:-bench_work/table1_cpu}
CATEGORY=${CATEGORY:-laptop}
FACTOR=${FACTOR:-4}
SEED=${SEED:-0}
PRESET=${PRESET:-cpu}
OUT=${OUT:-results/diagnostics/budget}
shopt -s nullglob
found=("$WORK/${CATEGORY}"_i*_v*_s*/cells/scapo_${PRESET}_s$SEED.scapo.json)
if [ "${#found[@]}" != 1 ]; then
  echo "scapo: bench/diagnostics/budget_diagnostic.sh: ${#found[@]} finished Table 1 cells scapo_${PRESET}_s$SEED of $CATEGORY in" \
    "$WORK (one expected); compute it first (bash bench/table1.sh --categories $CATEGORY --seeds $SEED) or point" \
    "WORK at the tables' work folder" >&2
  exit 2
fi
cell=${found[0]}
data=$(dirname "$(dirname "$cell")")
base=$data/predictions_scapo_${PRESET}_s$SEED.npz
case "$FACTOR" in ''|*[!0-9]*|0) echo "scapo: bench/diagnostics/budget_diagnostic.sh: FACTOR must be a positive integer" >&2; exit 2;; esac
# -P: import scapo from PYTHONPATH or the venv, not from this folder (python -c puts the current folder first)
code_commit=$("$PY" -P -c "from scapo.provenance import git_commit; print(git_commit())")
cell_commit=$("$PY" -P -c "import json, sys; print(json.load(open(sys.argv[1]))['computed_commit'])" "$cell")
if [ "$code_commit" != "$cell_commit" ]; then
  echo "bench/diagnostics/budget_diagnostic.sh: note: this code is at $code_commit, the Table 1 cell at $cell_commit" >&2
fi
# the epochs the cell's run trained (its run.json, read without importing torch; the preset's where it has none)
read -r e1 e2 < <("$PY" -P - "$data/run_scapo_${PRESET}_s$SEED/run.json" "$PRESET" <<'PY'
import json
import sys

try:
    p = json.load(open(sys.argv[1]))["preset"]
    print(int(p["stage1_epochs"]), int(p["stage2_epochs"]))
except (OSError, ValueError, KeyError, TypeError):
    from scapo.models.presets import get_preset

    p = get_preset(sys.argv[2])
    print(p.stage1_epochs, p.stage2_epochs)
PY
)
run=$WORK/budget/${CATEGORY}_x${FACTOR}_s$SEED
mkdir -p "$WORK/budget" "$OUT"
"$SCAPO" train --data "$data" --preset "$PRESET" --set "stage1_epochs=$((e1 * FACTOR))" \
  --set "stage2_epochs=$((e2 * FACTOR))" --seed "$SEED" --out "$run" --no-progress
[ -e "$run/predictions.npz" ] || "$SCAPO" predict --run "$run" --data "$data" --out "$run/predictions.npz" \
  --option refine_steps=0 --no-progress
"$PY" bench/diagnostics/compare_predictions.py --data "$data" --pred "$PRESET=$base" \
  --pred "$PRESET x$FACTOR=$run/predictions.npz" --commit "$PRESET=$cell_commit" \
  --commit "$PRESET x$FACTOR=$code_commit" --root "$(dirname "$(dirname "$WORK")")" \
  --out "$OUT/${CATEGORY}_x${FACTOR}_s$SEED"
