"""Where EAP-style's object frame breaks (issue 89): stage 0's own canonical frame against the final base frame.

For a trained EAP-style run and one split of a dataset (val by default): the frame consistency
(:func:`scapo.eval.frames.frame_consistency`, strict and against the category's declared symmetric ground truth) of
stage 0's whole-object frame ``R0 G_a`` (the frame stage 1's input is turned into) and of the predicted object frame
``T_cam_obj`` (the largest part's pose), each at the training density (the first interleaved subset of each cloud,
as :meth:`scapo.methods.eap.EAPNet.infer` reads poses). A stage-0 frame of one canonical frame with a scattered
base frame names stage 1 (the part split or the base's angle); a scattered stage-0 frame names stage 0.

    python bench/diagnostics/eap_stage0_frames.py --data DATA --run RUN [--split val] [--limit 240]

Prints one Markdown table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def frames(data: Path, run: Path, split: str, limit: int) -> dict:
    """``{"stage0": (strict, sym), "base": (strict, sym), "samples": M}`` for the first ``limit`` samples."""
    import numpy as np
    import torch

    from scapo.data import load
    from scapo.eval.evaluator import object_frame_twins
    from scapo.eval.frames import frame_consistency
    from scapo.methods import load_run
    from scapo.methods.learned import normalize_clouds

    ds = load(data, split)
    pts = ds.arrays(["points"])["points"][:limit]
    gt = object_frame_twins(ds)[:limit]
    method = load_run(run)
    net = method.net
    n = int(net.pc.points)
    R0, base = [], []
    with torch.no_grad():
        for i in range(0, len(pts), 32):
            p = torch.from_numpy(np.ascontiguousarray(pts[i:i + 32])).float()
            sub = p[:, torch.randperm(p.shape[1], generator=torch.Generator().manual_seed(0))[:n]]
            _, Rw, _ = net.canonicalise(normalize_clouds(sub)[0])
            R0.append(Rw.double().numpy())
            base.append(net.infer(p)["T_cam_obj"])
    T0 = np.tile(np.eye(4), (len(pts), 1, 1))
    T0[:, :3, :3] = np.concatenate(R0)
    Tb = np.concatenate(base)
    out = {"samples": len(pts)}
    for name, T in (("stage0", T0), ("base", Tb)):
        out[name] = (frame_consistency(T, gt[:, 0]), frame_consistency(T, gt))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--run", type=Path, required=True, help="a trained EAP-style run folder")
    ap.add_argument("--split", default="val", choices=("val", "test", "train"))
    ap.add_argument("--limit", type=int, default=240, help="samples scored (the first of the split)")
    a = ap.parse_args(argv)
    r = frames(a.data, a.run, a.split, a.limit)
    print(f"| frame ({a.split}, {r['samples']} samples) | consistency | consistency sym |\n|---|---|---|")
    for name, label in (("stage0", "stage 0 (R0 G_a)"), ("base", "object frame (largest part)")):
        print(f"| {label} | {r[name][0]:.2f} | {r[name][1]:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
