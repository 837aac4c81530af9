"""Where a weighted-principal SCAPO run puts its frame weights (``encoder.frame=weighted``, issue 52).

For every view of a split: the per-point weights of the frame (the softmax of ``SE3Encoder.frame_scores``, read with a
forward hook while the run predicts one-pass), their effective share of the points ``1 / (N sum w^2)`` (1: uniform,
the plain principal frame; small: a few points decide the frame) and the weight each ground-truth part receives
against its share of the points. A frame that ignores the joint state must rest on one part (e.g. a laptop's base).

    python bench/diagnostics/frame_weights.py RUN DATA [--split val] [--points 256] [--out FILE.json]

RUN: a trained SCAPO run folder with ``encoder.frame=weighted``; DATA: a dataset (``scapo generate``). Prints a
Markdown table; ``--out`` also writes it as JSON with the run's identity.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch


def frame_weights(run: str, data: str, split: str = "val", points: int = 256, seed: int = 0) -> dict:
    """Per-view frame weights of ``run`` on ``split`` of ``data``: a dict with ``ess`` (V,) (effective share of the
    points, in (0, 1]), ``part_weight`` (V, P) (weight mass per ground-truth part, background points dropped) and
    ``part_share`` (V, P) (the parts' share of the points), ``instance_id`` (V,) and the run's identity.

    Raises:
        SystemExit: the run's frame is not "weighted".
    """
    from scapo.data.dataset import load
    from scapo.models.predict import Predictor

    pred = Predictor.load(run, refine_steps=0)
    enc = pred.model.encoder
    if enc.cfg.frame != "weighted":
        raise SystemExit(f"scapo: {run} has encoder.frame={enc.cfg.frame!r}; give a run with encoder.frame=weighted")
    ds = load(data, split)
    arr = ds.arrays()
    rng = np.random.default_rng(seed)
    captured = []
    hook = enc.frame_scores.register_forward_hook(lambda m, i, o: captured.append(o.detach().squeeze(-1)))
    P = int(pred.model.cfg.num_parts)
    ess, pw, ps = [], [], []
    try:
        for v in range(len(arr["points"])):
            keep = np.flatnonzero(arr["part_label"][v] >= 0)
            idx = rng.choice(keep, size=min(points, len(keep)), replace=False)
            x = torch.as_tensor(arr["points"][v][idx], dtype=torch.float32)[None]
            captured.clear()
            with torch.no_grad():
                pred.model.frames(x)
            w = captured[-1].softmax(-1)[0].numpy().astype(np.float64)
            lab = arr["part_label"][v][idx]
            ess.append(1.0 / (len(w) * float((w ** 2).sum())))
            pw.append([float(w[lab == p].sum()) for p in range(P)])
            ps.append([float((lab == p).mean()) for p in range(P)])
    finally:
        hook.remove()
    return {"ess": np.array(ess), "part_weight": np.array(pw), "part_share": np.array(ps),
            "instance_id": arr["instance_id"], "identity": pred.identity}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run")
    ap.add_argument("data")
    ap.add_argument("--split", default="val")
    ap.add_argument("--points", type=int, default=256, help="points per view (the run's training density)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    from scapo.errors import ScapoError

    try:
        r = frame_weights(a.run, a.data, a.split, a.points)
    except ScapoError as e:  # a missing run or dataset: the message, no traceback
        msg = str(e)
        print(msg if msg.startswith("scapo:") else f"scapo: {msg}", file=sys.stderr)
        return 2
    P = r["part_weight"].shape[1]
    lines = [f"# Frame weights of {a.run} on {a.split} of {a.data} ({len(r['ess'])} views, {a.points} points)", "",
             "| statistic | value |", "|:--|--:|",
             f"| effective share of the points, median (1 = uniform) | {np.median(r['ess']):.3f} |",
             f"| effective share, 10th percentile | {np.percentile(r['ess'], 10):.3f} |"]
    for p in range(P):
        lines.append(f"| part {p}: weight mass, median / share of the points, median | "
                     f"{np.median(r['part_weight'][:, p]):.3f} / {np.median(r['part_share'][:, p]):.3f} |")
    print("\n".join(lines))
    if a.out:
        from scapo.provenance import provenance

        Path(a.out).write_text(json.dumps({"provenance": provenance(),
            "command": "python bench/diagnostics/frame_weights.py " + " ".join(sys.argv[1:] if argv is None else argv),
            "identity": r["identity"], "ess": r["ess"].tolist(), "part_weight": r["part_weight"].tolist(),
            "part_share": r["part_share"].tolist(), "instance_id": np.asarray(r["instance_id"]).tolist(),
            "table": lines}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
