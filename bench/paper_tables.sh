#!/usr/bin/env bash
# Issue 93's tables under the fair race's rules: Table 1 and Table 3 in the paper's viewpoints on the five synthetic
# categories (laptop, safe, eyeglasses, oven, washer), and Table 1 in EAP's data regime (every part rendered in a scene
# of its own, `--parts-alone`) on laptop and eyeglasses. Every trained cell at BUDGET charged core-minutes under the
# compute ledger (its one-time work charged, a cell over 110 % of its budget refused), one preset per method for
# every category (`cpu`), three training seeds, one-pass rows and the "+ refine" rows of Table 1, the test split read
# by the tables alone: their datasets use a data seed no one working on the methods has used (DATA_SEED, default 93;
# the ladder, the fair race and the earlier tables used 0, 1, 2, 5 and 9). Resumable per cell; one torch thread; at
# most one chain per core, paused with SIGSTOP while anything else heavy runs; every done cell, and the speeds its
# budget was planned from, kept in ARCHIVE (committed as the tables go: a new machine restores them).
#
#   WT=<clean worktree> WORK=<work> BUDGET=<core-minutes> bash bench/paper_tables.sh                 # the data only
#   WT=... WORK=... BUDGET=... TASKS="table1:laptop table1:safe table3:laptop" bash bench/paper_tables.sh  # a chain
#   WT=... WORK=... BUDGET=... FINISH=1 OUT=results bash bench/paper_tables.sh   # the tables of the finished cells
#   WT=... WORK=... BUDGET=... DRY_RUN=1 TASKS=... bash bench/paper_tables.sh    # the cells and which are done
#
# A task is TABLE:CATEGORY, TABLE one of table1, table3 (SCAPO's four ablations; its "full" row is Table 1's SCAPO
# cell, shared through the work folder) and parts (Table 1 with --parts-alone). Give two chains disjoint tasks. WT is a
# clean worktree of the commit the cells record (git worktree add); each bench runs from inside it. BUDGET is the
# smallest of 15, 30 and 45 core-minutes at which every trained method's val S is within 3 points and its frame
# consistency within 0.05 of its 45-minute values on the compute curve (bench/compute.sh); the tables' compute at B
# core-minutes: Table 1 5 x 4 trained methods x 3 seeds x B, Table 3 5 x 4 ablations x 3 x B, the parts-alone Table 1
# 2 x 4 x 3 x B (at 15: 15 + 15 + 6 = 36 core-hours of training, plus prediction and the speed runs).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
wt="${WT:?give WT, a clean worktree of the commit the cells record}"
work="$(realpath -m "${WORK:?give WORK, the work folder}")"
budget="${BUDGET:?give BUDGET, the charged core-minutes per trained cell (chosen on the compute curve)}"
data_seed="${DATA_SEED:-93}"
seeds="${SEEDS:-0,1,2}"
archive="$(realpath -m "${ARCHIVE:-$here/results/paper_tables_cells}")"
py="${PYTHON:-$here/.venv/bin/python}"
cats="laptop safe eyeglasses oven washer"
parts_cats="laptop eyeglasses"
if [ -n "$(git -C "$wt" status --porcelain --untracked-files=no)" ]; then
  echo "paper_tables.sh: $wt has uncommitted changes; the cells must come from one clean commit" >&2
  exit 2
fi
bench() {  # TABLE (table1, table3, parts), then options; from inside WT, so that its code is the code imported
  local table="$1"; shift
  local extra=()
  case "$table" in
    table1) extra=(table1 --name table1_synthetic_paper) ;;
    table3) extra=(table3 --name table3_ablation_paper) ;;
    parts) extra=(table1 --parts-alone --name table1_parts_alone) ;;
    *) echo "paper_tables.sh: unknown table $table (table1, table3 or parts)" >&2; return 2 ;;
  esac
  (cd "$wt" && OMP_NUM_THREADS=1 PYTHONPATH="$wt" "$py" -m scapo.cli bench "${extra[@]}" --viewpoints paper \
    --preset cpu --seed "$data_seed" --seeds "$seeds" --budget-minutes "$budget" --work "$work" \
    --archive "$archive" --no-progress "$@")
}
if [ -n "${FINISH:-}" ]; then  # into a staging folder first: a table written into WT's tree would make it dirty
  stage=$(mktemp -d)
  trap 'rm -rf "$stage"' EXIT
  bench table1 --categories "${cats// /,}" --finished-only --out "$stage"
  bench table3 --categories "${cats// /,}" --finished-only --out "$stage"
  bench parts --categories "${parts_cats// /,}" --finished-only --out "$stage"
  out="$(realpath -m "${OUT:-$here/results}")"
  mkdir -p "$out"
  cp -r "$stage"/. "$out"/
  echo "paper_tables.sh: tables written into $out"
  exit 0
fi
if [ -z "${TASKS:-}" ]; then  # the data step: every dataset generated (and pinned in the archive) before any chain
  bench table1 --categories "${cats// /,}" --data-only --workers 2
  bench parts --categories "${parts_cats// /,}" --data-only --workers 2
  exit 0
fi
# At most one chain per core (bench/fair_race.sh: a step's CPU time moves by 10-20 % when more processes are busy
# than there are cores, and the ledger then charges more for the same steps). PARALLEL=1 overrides.
running=$( (pgrep -f "scapo.cli bench (table1|table3|ladder)" || true) | wc -l)
if [ -z "${PARALLEL:-}" ] && [ -z "${DRY_RUN:-}" ] && [ "$running" -ge "$(nproc)" ]; then
  echo "paper_tables.sh: $running benches already run on this machine's $(nproc) cores; a cell's CPU time depends on" \
    "what runs beside it: wait for one to finish, or give PARALLEL=1" >&2
  exit 2
fi
for task in $TASKS; do
  table="${task%%:*}"; cat="${task#*:}"
  bench "$table" --categories "$cat" ${DRY_RUN:+--dry-run} --out "$work/out_${table}_$cat"
done
