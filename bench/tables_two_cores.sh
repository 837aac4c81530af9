#!/usr/bin/env bash
# Tables 1, 2 and 3 (issue 31) on a 2-core machine, every cell at the commit of this checkout: the settings of
# bench/table1.sh, bench/table2.sh and bench/table3.sh (cpu presets, data seed 1, 150 instances x 8 views per
# category, 30 of them test; training seeds 0,1,2 everywhere, Table 2's SJ rows included).
#
# Two chains, each pinned to one core with one torch thread, take tasks from one queue; a task is one table's
# cells of one category and one training seed. Seeds are the outer loop (every table's seed-0 cells come before
# any seed-1 cell), Table 1, then Table 3, then Table 2 within a seed. A chain holds a lock on the task's work
# folder and category while it runs it (flock: released when its process ends), so no dataset is generated, and
# no cell computed, twice at once (Table 3 shares Table 1's datasets and SCAPO cells). Resumable: `scapo bench`
# skips finished cells, and a task is marked done only when its bench call succeeds; after an interruption (a
# session's end) run this again. Refuses a checkout with uncommitted changes (ALLOW_DIRTY=1 to run anyway: the
# cells then record a -dirty commit and the tables refuse them).
#
# Every done cell is archived as it finishes (`scapo bench --archive`: its record, per-sample metrics, compressed
# predictions and run identity) into $OUT/tables_cells/table1_table3/ and $OUT/tables_cells/table2/, which are
# committed as the regeneration goes; a machine that loses the work folders (a new session's fresh machine) then
# regenerates the datasets and restores the archived cells instead of computing them again.
#
#   bash bench/tables_two_cores.sh            prepare the datasets (DATA=1, below), then start both chains in the
#                                             background (logs: $WORK1/logs/)
#   STATUS=1 bash bench/tables_two_cores.sh   what is done and what is running
#   DATA=1 bash bench/tables_two_cores.sh     only prepare the datasets: generate those of CATS1 and CATS2 (Table 3
#                                             uses Table 1's) in WORK1 / WORK2, make each the archive's pinned bytes
#                                             where it differs from them only by rounding (a machine of another CPU
#                                             kind; scapo.bench.archive.reconcile_dataset), pin the others, restore
#                                             their archived cells, and mark a category whose dataset would put cells
#                                             of a second dataset into the archive ($WORK/conflict/<category>: the
#                                             chains skip its tasks; scapo.bench.archive.archive_conflict). Cells
#                                             archived before datasets were pinned, on another CPU kind, are adopted
#                                             by this machine's regeneration of their dataset only by
#                                             bench/diagnostics/cross_cpu_check.py --adopt (scapo.bench.archive.adopt_dataset:
#                                             the cells must score the same on it and ICP computed again on its
#                                             inputs must give the archived predictions); run DATA=1 after it
#   FINISH=1 bash bench/tables_two_cores.sh   write the three tables from the finished cells into $OUT, and Table 1
#                                             under the eap and op-align protocols into $OUT/protocols/ (the datasets
#                                             must exist: after a fresh machine, run DATA=1 first)
#                                             The protocol re-scorings record the commit of this checkout when they
#                                             are scored, and a table refuses records of two commits: commit nothing
#                                             on this checkout while FINISH runs, and preview FINISH only with copies
#                                             of the archives (ARCHIVE1/ARCHIVE2/OUT in /tmp) and FINISH_PROTOCOLS=" ",
#                                             or remove $WORK1/*/cells/*.{eap,op-align}.* afterwards (never Table 2's
#                                             records in $WORK2, which are op-align cells themselves)
#
# CODE is the checkout whose code computes the cells (default: this one): a clean worktree of the commit the tables
# should record (git worktree add ../wtNN <commit>). The data step, STATUS and FINISH run this checkout's code, so
# that main's dataset pinning serves cells of an older commit (data generation has not changed since 74d416d).
# Issue 31, from main: CODE=../wt31 WORK1=../wt31/bench_work/table1_cpu WORK2=../wt31/bench_work/table2_cpu
# bash bench/tables_two_cores.sh (OUT defaults to this checkout's results/).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
HERE=$PWD
CODE=$(cd "${CODE:-$HERE}" && pwd)  # the cells' code
export PYTHONPATH="$HERE${PYTHONPATH:+:$PYTHONPATH}"  # this checkout's code, whatever the venv's editable install is
SCAPO=${SCAPO:-$HERE/.venv/bin/scapo}
WORK1=${WORK1:-bench_work/table1_cpu}  # Tables 1 and 3
WORK2=${WORK2:-bench_work/table2_cpu}  # Table 2 (realistic sensor, upright)
OUT=${OUT:-results}
SEEDS=${SEEDS:-0 1 2}
# Issue 31's Tables 1 and 3 are the whole sphere's (objects under uniform SO(3) rotations), made before the paper's
# viewpoints became the bench's default: table1.sh and table3.sh get --viewpoints sphere.
export VIEWPOINTS=${VIEWPOINTS:-sphere}
CATS1=${CATS1:-laptop safe eyeglasses oven washer}
CATS3=${CATS3:-laptop eyeglasses}
CATS2=${CATS2:-basket drawer laptop scissors suitcase}
QUEUE=$WORK1/queue
ARCHIVE1=${ARCHIVE1:-$OUT/tables_cells/table1_table3}  # the cells archive of Tables 1 and 3
ARCHIVE2=${ARCHIVE2:-$OUT/tables_cells/table2}

work_of() {  # TABLE: its work folder (Table 3 shares Table 1's)
  if [ "$1" = table2 ]; then echo "$WORK2"; else echo "$WORK1"; fi
}
archive_of() {  # TABLE: its cells archive
  if [ "$1" = table2 ]; then echo "$ARCHIVE2"; else echo "$ARCHIVE1"; fi
}

prepare_data() {  # this checkout's code: generate, reconcile, pin, restore; mark the categories in conflict
  local seeds c t work archive why
  seeds=$(echo "$SEEDS" | tr ' ' ',')
  for t in table1 table2; do
    if [ "$t" = table1 ]; then set -- $CATS1; work=$WORK1; archive=$ARCHIVE1
    else set -- $CATS2; work=$WORK2; archive=$ARCHIVE2; fi
    mkdir -p "$work/conflict"
    for c in "$@"; do
      SEEDS=$seeds WORK=$work bash bench/$t.sh --categories "$c" --data-only --archive "$archive" --no-progress
      why=$("$HERE/.venv/bin/python" -P -c 'import sys
from pathlib import Path
from scapo.bench.archive import archive_conflict
print(archive_conflict(Path(sys.argv[1]), Path(sys.argv[2])))' "$work/${c}_i150_v8_s1" "$archive")
      if [ -n "$why" ]; then
        echo "$why" > "$work/conflict/$c"
        echo "scapo: $t $c: no cell computed on this machine: $why" >&2
      else
        rm -f "$work/conflict/$c"
      fi
    done
  done
}

if [ -n "${DATA:-}" ]; then
  prepare_data
  exit 0
fi
if [ -n "${FINISH:-}" ]; then
  seeds=$(echo "$SEEDS" | tr ' ' ',')
  # The tables are written into a staging folder and copied into $OUT at the end: a table written into this
  # checkout's results/ makes it dirty, and the next table would then refuse to score from it.
  stage=$(mktemp -d)
  trap 'rm -rf "$stage"' EXIT
  # SEEDS is handed on comma-separated: the table scripts read it too (space-separated, scapo bench refused it)
  SEEDS=$seeds WORK=$WORK1 bash bench/table1.sh --finished-only --archive "$ARCHIVE1" --out "$stage"
  SEEDS=$seeds WORK=$WORK1 bash bench/table3.sh --finished-only --archive "$ARCHIVE1" --out "$stage"
  SEEDS=$seeds WORK=$WORK2 bash bench/table2.sh --finished-only --archive "$ARCHIVE2" --out "$stage"
  # Table 1's cells scored again under EAP's and OP-Align's released protocols (no training or prediction: the
  # same predictions; the scores of these files come from the code that runs FINISH, their provenance says so)
  for protocol in ${FINISH_PROTOCOLS:-eap op-align}; do
    SEEDS=$seeds WORK=$WORK1 bash bench/table1.sh --finished-only --archive "$ARCHIVE1" --protocol "$protocol" \
      --name "table1_synthetic_$protocol" --out "$stage/protocols"
  done
  mkdir -p "$OUT"
  cp -r "$stage"/. "$OUT"/
  echo "tables written into $OUT"
  exit 0
fi
tasks() {  # one line per task: TABLE CATEGORY SEED, in the order the chains take them
  local s c
  for s in $SEEDS; do
    for c in $CATS1; do echo "table1 $c $s"; done
    for c in $CATS3; do echo "table3 $c $s"; done
    for c in $CATS2; do echo "table2 $c $s"; done
  done
}

if [ -n "${STATUS:-}" ]; then
  mkdir -p "$QUEUE"
  n=0; d=0
  while read -r t c s; do
    n=$((n + 1))
    if [ -e "$QUEUE/${t}_${c}_s$s.done" ]; then d=$((d + 1)); state=done
    elif [ -e "$(work_of "$t")/conflict/$c" ]; then state="skipped here: $(cat "$(work_of "$t")/conflict/$c")"
    elif [ -e "$QUEUE/${t}_${c}_s$s.failed" ]; then state="failed (see $QUEUE/${t}_${c}_s$s.failed)"
    elif [ -e "$QUEUE/${t}_${c}_s$s.running" ]; then state="started $(cat "$QUEUE/${t}_${c}_s$s.running")"
    else state=todo; fi
    printf '%-7s %-11s seed %s  %s\n' "$t" "$c" "$s" "$state"
  done < <(tasks)
  echo "$d of $n tasks done (a started task whose chain has ended is taken again by the next run)"
  exit 0
fi

if [ -n "$(git -C "$CODE" status --porcelain --untracked-files=no 2>/dev/null)" ] && [ -z "${ALLOW_DIRTY:-}" ]; then
  echo "scapo: $CODE has uncommitted changes, so its cells would record a -dirty commit that the tables" \
    "refuse; commit them (or run from a clean worktree of the commit), or set ALLOW_DIRTY=1" >&2
  exit 2
fi
mkdir -p "$QUEUE" "$WORK1/logs" "$WORK1/locks" "$WORK2/locks"
[ -n "${SKIP_DATA:-}" ] || prepare_data  # a fresh machine: datasets made the pinned bytes before any cell

run_task() {  # TABLE CATEGORY SEED: that table's cells of one category and one training seed
  local t=$1 c=$2 s=$3 work
  work=$(work_of "$t")
  OMP_NUM_THREADS=1 PYTHONPATH="$CODE" taskset -c "$CORE" "$SCAPO" bench "$t" --preset cpu --seed 1 --seeds "$s" --categories "$c" \
    --work "$work" --archive "$(archive_of "$t")" --no-progress --out "$work/logs/${t}_${c}_s$s"
}

chain() {  # take the first task that is neither done nor locked by the other chain; stop when none is left
  local t c s lock rc ran
  while :; do
    ran=0
    while read -r t c s; do
      [ -e "$QUEUE/${t}_${c}_s$s.done" ] && continue
      [ -e "$(work_of "$t")/conflict/$c" ] && continue  # its dataset is not the archive's (prepare_data)
      grep -qs "run $RUN_ID" "$QUEUE/${t}_${c}_s$s.failed" && continue  # failed in this run: not again
      lock="$(work_of "$t")/locks/$c.lock"
      exec 9>"$lock"
      if ! flock -n 9; then exec 9>&-; continue; fi
      [ -e "$QUEUE/${t}_${c}_s$s.done" ] && { exec 9>&-; continue; }  # finished while we waited
      echo "core $CORE $(date -u +%FT%TZ)" > "$QUEUE/${t}_${c}_s$s.running"
      echo "=== $(date -u +%FT%TZ) core $CORE: $t $c seed $s"
      run_task "$t" "$c" "$s" && rc=0 || rc=$?
      rm -f "$QUEUE/${t}_${c}_s$s.running"
      if [ "$rc" = 0 ]; then
        touch "$QUEUE/${t}_${c}_s$s.done"; rm -f "$QUEUE/${t}_${c}_s$s.failed"
      else
        echo "exit $rc at $(date -u +%FT%TZ), core $CORE, run $RUN_ID; log: $WORK1/logs/core$CORE.log" \
          > "$QUEUE/${t}_${c}_s$s.failed"
      fi
      echo "=== $(date -u +%FT%TZ) core $CORE: $t $c seed $s exit $rc"
      exec 9>&-
      ran=1
      break  # back to the top of the queue: an earlier task may be free now
    done < <(tasks)
    [ "$ran" = 1 ] || break
  done
  echo "=== $(date -u +%FT%TZ) core $CORE: no task left for this chain"
}

RUN_ID=$(date -u +%Y%m%dT%H%M%S)-$$
for core in 0 1; do
  nohup setsid env CORE=$core RUN_ID="$RUN_ID" bash -c "$(declare -p SCAPO CODE WORK1 WORK2 ARCHIVE1 ARCHIVE2 SEEDS CATS1 CATS2 CATS3 QUEUE); \
    $(declare -f tasks work_of archive_of run_task chain); set +e; chain" >> "$WORK1/logs/core$core.log" 2>&1 &
  sleep 2  # the first chain takes its lock before the second looks
done
echo "started; follow with: tail -f $WORK1/logs/core0.log $WORK1/logs/core1.log; STATUS=1 bash $0 for the queue"
