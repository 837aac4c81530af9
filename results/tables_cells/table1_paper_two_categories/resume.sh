#!/usr/bin/env bash
# Resume the paper-regime Table 1 at 70ca330 (issue 52) on this or another machine: a clean worktree of 70ca330, a
# work folder given the archived speeds (so every method gets the schedule the archived cells were trained with), the
# datasets generated (or found) and their archived cells restored, then the two chains of chains.sh (split by
# predicted cost; each skips its done cells), then the table of every finished cell into $OUT (default
# <work>/out; copy it into results/ and commit). Run from anywhere, with main's .venv set up (bash scripts/setup.sh).
#   bash results/tables_cells/table1_paper_two_categories/resume.sh            # WORK=..., WT=..., OUT=... to move them
#   FINISH=1 bash results/tables_cells/table1_paper_two_categories/resume.sh   # only the table of the finished cells
set -euo pipefail
archive="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
main="$(cd "$archive/../../.." && pwd)"
rev=70ca330
wt="${WT:-$main/bench_work/wt_$rev}"
work="${WORK:-$main/bench_work/table1_paper_$rev}"
out="${OUT:-$work/out}"
S="$main/.venv/bin/scapo"
[ -d "$wt" ] || git -C "$main" worktree add -f --detach "$wt" "$rev"
[ "$(git -C "$wt" rev-parse --short=7 HEAD)" = "$rev" ] || { echo "scapo: $wt is not at $rev" >&2; exit 2; }
mkdir -p "$work/speeds"
cp -n "$archive"/speeds/*.json "$work/speeds/"
export PYTHONPATH="$wt" OMP_NUM_THREADS=1
cd "$wt"
common=(bench table1 --viewpoints paper --seeds 0,1,2 --budget-minutes 5 --no-refine-rows --work "$work"
        --name table1_paper_two_categories --no-progress --archive "$archive")
if [ -z "${FINISH:-}" ]; then
  "$S" "${common[@]}" --categories laptop,eyeglasses --data-only --workers 2
  ( "$S" "${common[@]}" --categories laptop --out "$work/out_a1" --methods scapo
    "$S" "${common[@]}" --categories laptop,eyeglasses --out "$work/out_a2" --methods op-align ) > "$work/chain_a.log" 2>&1 &
  a=$!
  sleep 60
  ( "$S" "${common[@]}" --categories laptop,eyeglasses --out "$work/out_b1" --methods npcs,eap,icp
    "$S" "${common[@]}" --categories eyeglasses --out "$work/out_b2" --methods scapo ) > "$work/chain_b.log" 2>&1 &
  b=$!
  wait $a $b
fi
"$S" "${common[@]}" --categories laptop,eyeglasses --finished-only --out "$out"
