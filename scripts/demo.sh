#!/usr/bin/env bash
# Set up (if needed) and run the main job: build assets, render, run ICP, evaluate, write a table and a figure.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/setup.sh"
exec "${SCAPO_VENV:-$here/.venv}/bin/scapo" demo "$@"
