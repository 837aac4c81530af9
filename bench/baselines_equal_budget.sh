#!/usr/bin/env bash
# Issue 30's acceptance experiment: the -style baselines with the components that define them (OP-Align-style,
# EAP-style, NPCS-style with per-part NPCS) at the equal cpu budget (the same 256 training points and the epochs that
# fill 15 minutes of training per cell on one core, measured by `scapo bench perf --what train --data`), on issue 29's
# Table 1 data (laptop and eyeglasses, 150 instances x 8 views, 30 test instances each, uniform SO(3) rotations,
# data seed 1), three training seeds, one-pass and "+ refine" rows. The versions before issue 30 are the rows of
# results/table1_two_categories (commit 66524f5, the same datasets: their hashes are in both provenances).
# Two chains, each pinned to one core with one torch thread (laptop on core 0, eyeglasses on core 1), seeds in the
# outer loop. Resumable per cell: rerun after an interruption. Run it from a clean worktree of the commit the table
# should record; when both chains are done (or to see the cells so far) write the table with:
#   FINISH=1 bash bench/baselines_equal_budget.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# the same two pinned chains (and FINISH=1) as bench/table1_two_categories.sh, for these methods, folder and name
WORK=${WORK:-bench_work/baselines_equal_budget} OUT=${OUT:-results/baselines_equal_budget} \
  METHODS=${METHODS:-npcs,eap,op-align} NAME=baselines_equal_budget exec bash bench/table1_two_categories.sh "$@"
