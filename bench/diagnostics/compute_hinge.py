"""Accuracy against training compute with the hinge prediction steps (issue 52): the compute curve's cells
(``scapo bench compute``: one training run per method and budget, one-pass predictions on the curve's dataset) scored
again after ``hinge=true, hinge_axis=true, hinge_frames=true, hinge_view_prior=true`` (:mod:`scapo.steps.hinge`; no
training: the steps read each prediction and its points), beside the one-pass rows, as the curve's table and figure.

    python bench/diagnostics/compute_hinge.py --data DATA --pred BUDGET:LABEL=PREDICTIONS.npz [...] --steps \\
        BUDGET:LABEL=N [...] \
        --out results --name accuracy_vs_compute_hinge --command "how the predictions were made"

Each ``--pred`` is one row (val split): S, D, R and their medians from :func:`scapo.eval.evaluator.evaluate`, and the
object-frame consistency (:func:`scapo.eval.frames.split_consistency`). ``--steps`` gives a row's training steps
(from the cell's record). Writes ``<out>/<name>.{md,json,csv,png}`` (:func:`scapo.bench.compute.write_curve`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def record(data: Path, label: str, budget: float, path: str, steps) -> dict:
    """One row of the curve for the predictions file ``path`` (val split of ``data``)."""
    from scapo.eval.evaluator import evaluate
    from scapo.eval.frames import split_consistency
    from scapo.eval.predictions import Predictions
    from scapo.provenance import provenance

    p = Predictions.load(path)
    s = evaluate(data, p, split="val").summary
    strict, sym = split_consistency(data, p, "val")
    keys = ("S", "D", "D_median", "C", "R", "R_median", "R_sym", "R_sym_median", "R_sym_over90")
    return {"method": label, "budget_min": budget, "seed": int(p.info.get("seed") or 0), "file": path,
            "wall": {"train_steps": steps}, "frame_consistency": strict, "frame_consistency_sym": sym,
            "resampling_deg": None, **{k: float(s[k]) for k in keys}, "provenance": provenance(),
            "dataset_hash": p.dataset_hash}


def main(argv=None) -> int:
    from scapo.bench.compute import write_curve
    from scapo.data import load
    from scapo.errors import ScapoError

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--pred", action="append", default=[], help="BUDGET:LABEL=PREDICTIONS.npz")
    ap.add_argument("--steps", action="append", default=[], help="BUDGET:LABEL=TRAINING_STEPS")
    ap.add_argument("--out", required=True)
    ap.add_argument("--name", default="accuracy_vs_compute_hinge")
    ap.add_argument("--command", default="", help="how the predictions files were made (recorded in the table)")
    a = ap.parse_args(argv)
    try:
        rows = []
        for item in a.pred:
            key, _, path = item.partition("=")
            budget, _, label = key.partition(":")
            rows.append((float(budget), label, path))
        steps = {}
        for item in a.steps:
            key, _, n = item.partition("=")
            budget, _, label = key.partition(":")
            steps[(float(budget), label)] = int(n)
    except ValueError:
        print("scapo: write --pred BUDGET:LABEL=FILE.npz and --steps BUDGET:LABEL=N (BUDGET in core-minutes)",
              file=sys.stderr)
        return 2
    missing = [p for _, _, p in rows if not Path(p).is_file()]
    if not rows or missing or not all(label for _, label, _ in rows) or not Path(a.data).is_dir():
        print(f"scapo: {missing[0] if missing else 'no --pred BUDGET:LABEL=FILE'}: give a dataset folder (--data) and "
              "predictions files", file=sys.stderr)
        return 2
    try:
        data = Path(a.data)
        card = load(data, "val").card
        cfg = card.get("config", {})
        records = [record(data, label, b, path, steps.get((b, label.split("+")[0]), steps.get((b, label))))
                   for b, label, path in rows]
        cmd = "python bench/diagnostics/compute_hinge.py " + " ".join(sys.argv[1:] if argv is None else argv)
        meta = {"name": a.name, "category": card.get("category", "?"), "rung": card.get("viewpoints", "?"),
                "split": "val", "dataset": data.name, "instances": cfg.get("instances"), "views": cfg.get("views"),
                "train_views": cfg.get("train_views"), "data_seed": cfg.get("seed"), "preset": "cpu",
                "protocol": "scapo", "machine": records[0]["provenance"].get("device", "-"),
                "command": cmd + (f" (predictions: {a.command})" if a.command else ""),
                "predictions": "one-pass and with the hinge steps",
                "note": "Rows named `<method>+hinge-axis+hinge-frames+view-prior` are the same cells' predictions "
                        "after the hinge steps (`hinge=true, hinge_axis=true, hinge_frames=true, "
                        "hinge_view_prior=true`, `scapo.steps.hinge`): no training, so their compute is the cell's. "
                        "Their steps are the cell's training steps."}
        paths = write_curve(records, Path(a.out), meta)
    except (ScapoError, OSError) as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    print("wrote " + ", ".join(map(str, paths)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
