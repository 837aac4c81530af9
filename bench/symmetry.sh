#!/usr/bin/env bash
# Symmetries of the nine procedural categories, measured (issue 29): `scapo assets symmetry` per category
# (declared symmetries and whether they hold on the meshes, undeclared self-maps of the posed meshes, part
# symmetries, and the share of 10 instances x 10 views, seed 5, that an undeclared pose explains as well as the
# truth, by the full-surface one-sided and the visible-surface two-sided criteria). Resumable: a category whose
# JSON exists is skipped. CATEGORIES="safe oven" picks some (two shells, one per core, each take a share).
#   OUT=results/symmetry/after bash bench/symmetry.sh            # the current assets
# then the table of every asset version side by side (results/symmetry/README.md):
#   python bench/diagnostics/symmetry_table.py --column v1=results/symmetry/before --column v2=results/symmetry/v2 \
#     --column v3=results/symmetry/after --out results/symmetry/README.md
# The v1 column was measured by the same code on the assets of commit baf2096, v2 at 8dfd1b4 (see results/symmetry/).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=${SCAPO:-.venv/bin/scapo}
OUT=${OUT:-results/symmetry/after}
mkdir -p "$OUT"
for c in ${CATEGORIES:-laptop suitcase scissors basket safe oven drawer eyeglasses washer}; do
  [ -f "$OUT/$c.json" ] && { echo "$c: done ($OUT/$c.json)"; continue; }
  $S assets symmetry --category "$c" --instances 10 --views 10 --seed 5 --json "$OUT/$c.json" | tee "$OUT/$c.txt"
done
