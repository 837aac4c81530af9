#!/usr/bin/env bash
# Table 1 (synthetic categories of the paper) for the methods given (default: icp).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec .venv/bin/scapo bench table1 --methods "${METHODS:-icp}" --categories laptop,safe,eyeglasses,oven,washer \
  --instances "${INSTANCES:-40}" --views "${VIEWS:-20}" --work "${WORK:-bench_work}" --out results "$@"
