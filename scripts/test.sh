#!/usr/bin/env bash
# Set up (if needed) and run the test suite in two pytest-xdist workers (SCAPO_TEST_WORKERS; 0 runs it in this
# process). Extra arguments go to pytest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$here/scripts/setup.sh"
cd "$here"
exec "${SCAPO_VENV:-$here/.venv}/bin/python" -m pytest -n "${SCAPO_TEST_WORKERS:-2}" "$@"
