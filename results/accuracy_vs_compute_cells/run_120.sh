#!/usr/bin/env bash
# The compute curve's 120-core-minute OP-Align-style and EAP-style cells (issue 52; laptop, paper rung, val, seed 0),
# at 12dd86d, the commit of the curve's other cells, with the schedules of that curve's machine (an AMD EPYC whose
# speed files were not kept): speeds/*.json are RECONSTRUCTED clouds/s that reproduce the recorded 5/15/45-minute
# epochs (OP-Align-style 5, 16, 47; EAP-style 10, 30, 89) and give 125 and 237 epochs at 120 (each file's note).
# Then the curve of every finished cell into results/ with main's code (it scores the new cells' frame consistency
# as the others', CONSISTENCY_VERSION 2). Resumable: a cell's training resumes from its run's last epoch.
#   bash results/accuracy_vs_compute_cells/run_120.sh              # both cells side by side, then FINISH
#   FINISH=1 bash results/accuracy_vs_compute_cells/run_120.sh     # only the curve of the finished cells
# WORK (bench_work/compute_12dd86d), WT (bench_work/wt_12dd86d), DATA (a finished laptop_i150_v8_t64_s0_paper folder
# to link instead of rendering it, e.g. the table's), OUT (results).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
main="$(cd "$here/../.." && pwd)"
rev=12dd86d
wt="${WT:-$main/bench_work/wt_$rev}"
work="${WORK:-$main/bench_work/compute_$rev}"
S="$main/.venv/bin/scapo"
ds=laptop_i150_v8_t64_s0_paper
mkdir -p "$work/speeds"
cp -n "$here"/speeds/*.json "$work/speeds/"
if [ ! -e "$work/$ds" ] && [ -n "${DATA:-}" ]; then ln -s "$(cd "$DATA" && pwd)" "$work/$ds"; fi
if [ -z "${FINISH:-}" ]; then
  [ -d "$wt" ] || git -C "$main" worktree add -f --detach "$wt" "$rev"
  [ "$(git -C "$wt" rev-parse --short=7 HEAD)" = "$rev" ] || { echo "scapo: $wt is not at $rev" >&2; exit 2; }
  run() { (cd "$wt" && PYTHONPATH="$wt" OMP_NUM_THREADS=1 "$S" "$@"); }
  # the dataset (06fa29ec; speeds are there already, so nothing is measured)
  run bench table1 --viewpoints paper --categories laptop --methods op-align,eap --seeds 0 --budget-minutes 5 \
    --no-refine-rows --work "$work" --data-only --no-progress
  for m in op-align eap; do
    run bench compute --from-table --category laptop --seeds 0 --budgets 120 --methods "$m" --work "$work" \
      --out "$work/out_$m" --no-progress > "$work/$m.log" 2>&1 &
  done
  wait
fi
# the curve's other cells, restored from the committed curve (their predictions are not kept; their records are
# final: consistency_version 2), then the curve of every finished cell with this checkout's code
"$main/.venv/bin/python" - "$main/results/accuracy_vs_compute.json" "$work" <<'PY'
import json
import sys
from pathlib import Path

curve, work = json.loads(Path(sys.argv[1]).read_text()), Path(sys.argv[2])
for r in curve["records"]:
    path = work / "compute" / f"b{r['budget_min']:g}" / "laptop" / "paper" / f"{r['method']}_s{r['seed']}.json"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({k: v for k, v in r.items() if k != "budget_min"}, indent=1))
PY
"$S" bench compute --from-table --category laptop --seeds 0 --budgets 5,15,45,120 --work "$work" \
  --out "${OUT:-$main/results}" --finished-only --no-progress
