#!/usr/bin/env bash
# Issue 88's fair race (results/fair_race/): the ladder's paper rung (single views in the paper's viewpoints, 150
# instances, 8 views per val/test instance, 64 per training instance, data seed 1), scored on val, three training
# seeds, every trained method at BUDGET (15) charged core-minutes under the compute ledger, one preset per method
# (`cpu`), SCAPO's per-category presets as labelled rows. Resumable per cell; one torch thread; at most one chain per
# core (below), paused with SIGSTOP while anything else heavy runs, on one kind of CPU per side.
#
#   WT=/path/to/clean/worktree WORK=/path/to/work CHAIN="op-align scapo" bash bench/fair_race.sh   # a chain of cells
#   WT=... WORK=... VARIANTS=1 bash bench/fair_race.sh    # SCAPO's per-category presets (labelled rows; after the
#                                                         # chain with scapo, whose cells it would otherwise train)
#   WT=... WORK=... FINISH=1 OUT=results/fair_race bash bench/fair_race.sh   # the tables of the finished cells
#   CATEGORIES="eyeglasses" ...                           # any of the above on some categories (default: laptop
#                                                         # eyeglasses): two chains of one method, one per category
#
#   WORK=... ARCHIVE=results/fair_race/cells/NAME bash bench/fair_race.sh   # keep the finished cells' records and
#                                                         # speed files (no predictions, no runs)
#   WORK=... RESTORE=results/fair_race/cells/NAME bash bench/fair_race.sh   # put them back into a new work folder
#
# WT: a clean worktree of the commit the cells record (git worktree add); its code computes the cells (each ladder
# runs from inside WT: run from elsewhere, python -m would import the scapo of the current folder). Several chains
# may share WORK (each its own methods) once the data exist; the data step runs in the first chain. A restored cell
# is not computed again (its record is found); check that the regenerated datasets have the records' hashes.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
work="${WORK:?give WORK, the work folder}"
if [ -n "${ARCHIVE:-}" ]; then  # records and speed files, their paths relative to WORK/ladder
  (cd "$work/ladder" && { find . -maxdepth 1 -name 'speed_*.json'
     find . -mindepth 3 -maxdepth 3 -path './*/paper/*' -name '*_s[0-9]*.json'; } \
     | while read -r f; do install -D -m 644 "$f" "$here/$ARCHIVE/$f"; done)
  echo "fair_race.sh: archived $(find "$here/$ARCHIVE" -name '*.json' | wc -l) files into $ARCHIVE"
  exit 0
fi
if [ -n "${RESTORE:-}" ]; then  # never over a cell of the work folder
  (cd "$here/$RESTORE" && find . -name '*.json' -print0 | while IFS= read -r -d '' f; do
     [ -e "$work/ladder/$f" ] || install -D -m 644 "$f" "$work/ladder/$f"; done)
  echo "fair_race.sh: restored $RESTORE into $work/ladder"
  exit 0
fi
wt="${WT:?give WT, a clean worktree of the commit the cells record}"
# At most one chain per core: a step's CPU time moves by 10-20 % when more processes are busy than there are cores
# (the ledger then charges more for the same steps); one other chain beside a speed run changed it by under 3 %
# (OP-Align-style: 32.05 and 31.16 clouds/s alone, 31.78 and 31.06 beside). PARALLEL=1 overrides.
running=$( (pgrep -f "scapo.cli bench ladder" || true) | wc -l)
if [ -z "${PARALLEL:-}" ] && [ -z "${FINISH:-}" ] && [ "$running" -ge "$(nproc)" ]; then
  echo "fair_race.sh: $running ladders already run on this machine's $(nproc) cores; a cell's CPU time depends on" \
    "what runs beside it: wait for one to finish, or give PARALLEL=1" >&2
  exit 2
fi
py="${PYTHON:-$here/.venv/bin/python}"
budget="${BUDGET:-15}"
cats="${CATEGORIES:-laptop eyeglasses}"
if [ -n "$(git -C "$wt" status --porcelain --untracked-files=no)" ]; then
  echo "fair_race.sh: $wt has uncommitted changes; the cells must come from one clean commit" >&2
  exit 2
fi
work="$(realpath -m "$work")"
ladder() {  # category, then ladder options; run from inside WT, so that its code is the code imported
  local cat="$1"; shift  # (python -m puts the current folder first on sys.path, before PYTHONPATH)
  (cd "$wt" && OMP_NUM_THREADS=1 PYTHONPATH="$wt" "$py" -m scapo.cli bench ladder --category "$cat" --rungs paper \
    --seeds 0,1,2 --instances 150 --views 8 --train-views 64 --budget-minutes "$budget" --seed 1 --work "$work" \
    --no-progress "$@")
}
variants() {  # SCAPO's per-category preset of a category, where it has one
  case "$1" in
    laptop) echo "--variant scapo:cpu-laptop:preset=cpu-laptop" ;;
    eyeglasses) echo "--variant scapo:cpu-eyeglasses:preset=cpu-eyeglasses" ;;
  esac
}
for cat in $cats; do
  ladder "$cat" --data-only --workers 2 --methods scapo
done
if [ -n "${FINISH:-}" ]; then
  for cat in $cats; do
    # shellcheck disable=SC2046
    ladder "$cat" --finished-only --methods "${METHODS:-scapo,op-align,eap,npcs}" $(variants "$cat") \
      --out "$(realpath -m "${OUT:-$work/out}")"
  done
  exit 0
fi
if [ -n "${VARIANTS:-}" ]; then
  for cat in $cats; do
    # shellcheck disable=SC2046
    ladder "$cat" --methods scapo $(variants "$cat") --out "$work/out_variants"  # after the scapo chain
  done
  exit 0
fi
for m in ${CHAIN:-op-align scapo npcs eap}; do
  for cat in $cats; do
    ladder "$cat" --methods "$m" --out "$work/out_$m"
  done
done
