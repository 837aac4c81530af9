#!/usr/bin/env bash
# Generation throughput next to the bare SAPIEN render-only rate (same objects, views, workers).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec .venv/bin/scapo bench perf --category "${CATEGORY:-laptop}" --instances 20 --views 30 --workers 1,2 \
  --out results/perf "$@"
