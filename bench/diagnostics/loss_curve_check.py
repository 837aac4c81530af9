"""Issue 30, step 3: the speed rewrites keep each trained method's loss curve (the same losses within rounding on a
fixed seed). Trains every trained method's ``cpu`` preset for a few capped epochs with ``scapo train`` from two
checkouts (BEFORE, AFTER: e.g. worktrees of the commits before and after the rewrite) on one dataset, seed 0, one
torch thread, plus a seed-1 run at AFTER as the scale of a real change; writes, per method, the largest relative
difference of the total loss over the steps (BEFORE vs AFTER seed 0, and seed 0 vs seed 1) and the mean total of
the last 10 steps of each.

    python bench/diagnostics/loss_curve_check.py --before /work/wt_base --after . --data DATASET --out results/perf
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

CAPS = {  # a few short epochs of each method's cpu preset (enough steps to see rounding grow)
    "scapo": ["stage1_epochs=2", "stage2_epochs=2", "max_steps_per_epoch=15"],
    "npcs": ["epochs=3", "max_steps_per_epoch=20"],
    "eap": ["epochs=3", "max_steps_per_epoch=20"],
    "op-align": ["epochs=3", "max_steps_per_epoch=20"],
}


def train(tree: Path, method: str, data: Path, out: Path, seed: int) -> list[float]:
    """Run ``scapo train`` from ``tree``; the total loss of every logged step."""
    if not (out / "log.csv").exists() or not (out / "timing.json").exists():
        env = {**os.environ, "PYTHONPATH": str(tree.resolve()), "OMP_NUM_THREADS": "1"}
        cmd = [sys.executable, "-m", "scapo.cli", "train", "--method", method, "--data", str(data), "--out", str(out),
               "--preset", "cpu", "--seed", str(seed), "--no-progress"]
        for s in CAPS[method]:
            cmd += ["--set", s]
        subprocess.run(cmd, check=True, env=env, cwd=tree, stdout=subprocess.DEVNULL)
    with open(out / "log.csv", newline="") as f:
        return [float(r["total"]) for r in csv.DictReader(f)]


def rel_diff(a: list[float], b: list[float]) -> float:
    n = min(len(a), len(b))
    return max(abs(x - y) / max(abs(y), 1e-12) for x, y in zip(a[:n], b[:n]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True)
    ap.add_argument("--after", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("bench_work/loss_curve_check"))
    ap.add_argument("--out", type=Path, default=Path("results/perf"))
    ap.add_argument("--methods", default="scapo,npcs,eap,op-align")
    a = ap.parse_args()
    commits = {k: subprocess.run(["git", "-C", str(t), "rev-parse", "--short", "HEAD"], capture_output=True,
                                 text=True, check=True).stdout.strip() for k, t in (("before", a.before),
                                                                                      ("after", a.after))}
    rows = []
    t0 = time.time()
    for m in a.methods.split(","):
        before = train(a.before, m, a.data, a.work / f"{m}_before_s0", 0)
        after = train(a.after, m, a.data, a.work / f"{m}_after_s0", 0)
        seed1 = train(a.after, m, a.data, a.work / f"{m}_after_s1", 1)
        last = lambda v: round(sum(v[-10:]) / len(v[-10:]), 5)  # noqa: E731
        rows.append({"method": m, "steps": len(after), "max_rel_diff_before_after": f"{rel_diff(after, before):.2e}",
                     "max_rel_diff_seed0_seed1": f"{rel_diff(seed1, after):.2e}",
                     "last10_total_before": last(before), "last10_total_after": last(after),
                     "last10_total_after_seed1": last(seed1)})
        print(rows[-1], flush=True)
    sys.path.insert(0, str(a.after.resolve()))
    from scapo.bench.perf import write_perf

    write_perf(rows, a.out, "train_loss_check", before_commit=commits["before"], after_commit=commits["after"],
               data=str(a.data), caps=json.dumps(CAPS), wall_s=round(time.time() - t0, 1), threads=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
