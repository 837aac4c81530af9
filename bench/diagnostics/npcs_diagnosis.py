"""Where the supervised NPCS-style row loses its accuracy: a ladder from ground-truth maps to the trained network, each
rung scored by the project's evaluator on one split (val for choices, test for the sanity check's explanation).

    python bench/diagnostics/npcs_diagnosis.py --data DATA --run RUN [--run RUN ...] --split val --out \\
        results/paper_regime/x.json
    python bench/diagnostics/npcs_diagnosis.py --digest LADDER.json [...]   # a Markdown table of ladders, means \\
        over their runs

Rungs (each one changes one thing against the row above it; the pose and joint half is NPCS-style's own
``NPCSNet.fit_poses``, RANSAC-Umeyama at the run's preset, so only the per-point inputs change):

- ``oracle``: ground-truth part labels, NAOCS and per-part NPCS (each part's box over the split's views of its
  instance, as training derives it); what the pose fitting and the evaluator give with perfect network outputs.
- ``net labels + GT maps``: the network's labels, ground-truth coordinates (the cost of segmentation errors).
- ``GT labels + net maps``: ground-truth labels, the network's coordinates (the cost of coordinate errors).
- ``net (all points)``: the 1024-point cloud at once (what the committed Tables 1-3 did; ``--option
  infer_points=100000``).
- ``net (infer_points=n)``: the cloud split into interleaved random subsets of about n points (n = the training's
  point count, 256 in ``cpu``, is the method's default: the density the network's k-nearest-neighbour
  patches were trained at; :class:`scapo.methods.npcs.NPCSOptions`).

Besides each rung's S, R, R sym (mean and median), D and C, the per-point quality of the network's outputs on object
points: segmentation accuracy, and the mean L2 error of its NAOCS and per-part NPCS on the true part's map (units of
the object's bbox diagonal, resp. the part box's diagonal), for both inference modes, and the first two on 240
training clouds (spread over the training split): a network as wrong on its training clouds as on held-out ones
underfits (capacity or budget), one far better on them overfits.

Errors: a missing dataset or run ends with a ``scapo:`` message (exit 2).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch


def _predictions(a: dict, out: dict, split: str, ds, label: str):
    from scapo.eval import Predictions

    M = len(a["points"])
    return Predictions(method=label, instance_id=a["instance_id"], view_id=a["view_id"], split=np.full(M, split),
                       part_label=out["part_label"].astype(np.int64), part_pose=out["part_pose"],
                       joint_parts=a["joint_parts"], joint_type=a["joint_type"], joint_axis=out["joint_axis"],
                       joint_pivot=out["joint_pivot"], joint_state=out["joint_state"], T_cam_obj=out["T_cam_obj"],
                       needs_alignment=False, dataset_hash=ds.dataset_hash)


def ladder(data: Path, run: Path, split: str, infer_points: int, batch: int = 32, train_clouds: int = 240) -> dict:
    """Every rung (module docstring) for one run on ``split``; returns ``{"rungs": {name: summary}, "maps": {...}}``."""
    from scapo.data import load
    from scapo.eval import evaluate
    from scapo.methods import load_run
    from scapo.methods.learned import normalize_clouds
    from scapo.methods.npcs import part_boxes

    ds = load(data, split)
    a = ds.arrays()
    method = load_run(run, device="cpu")
    net = method.module
    boxes = part_boxes(a, ds.card, method.preset).get("part_box")  # (M, P, 4); None without per-part NPCS
    M, N = a["part_label"].shape
    P = net.P
    lab_gt = a["part_label"]
    obj = lab_gt >= 0
    naocs_gt = np.repeat(a["npcs"].astype(np.float64)[:, :, None], P, 2)  # every map holds the point's NAOCS
    pnpcs_gt = None
    if boxes is not None:
        box_pt = boxes[np.arange(M)[:, None], np.clip(lab_gt, 0, None)]  # (M, N, 4)
        pnpcs_gt = np.repeat(((a["npcs"] - box_pt[..., :3]) / box_pt[..., 3:])[:, :, None], P, 2).astype(np.float64)
    pts = a["points"].astype(np.float64)
    scale = normalize_clouds(torch.from_numpy(a["points"]).float())[2].double().numpy()

    nets = {}
    maps = {}
    for mode in (0, infer_points):
        net.infer_points = mode
        lo, co, pa = [], [], []
        with torch.no_grad():
            for i in range(0, M, batch):
                x, y, z = net.outputs(torch.from_numpy(a["points"][i:i + batch]))
                lo.append(x.argmax(-1).numpy())
                co.append(y.double().numpy())
                pa.append(None if z is None else z.double().numpy())
        lab, co = np.concatenate(lo), np.concatenate(co)
        pa = None if pa[0] is None else np.concatenate(pa)
        nets[mode] = (lab, co, pa)
        at = np.clip(lab_gt, 0, None)
        co_t = np.take_along_axis(co, at[:, :, None, None].repeat(3, -1), 2)[:, :, 0]
        maps[f"infer_points={mode}"] = {
            "seg_accuracy": float((lab[obj] == lab_gt[obj]).mean()),
            "naocs_l2": float(np.linalg.norm(co_t - a["npcs"], axis=-1)[obj].mean()),
        }
        if pa is not None:
            pa_t = np.take_along_axis(pa, at[:, :, None, None].repeat(3, -1), 2)[:, :, 0]
            maps[f"infer_points={mode}"]["part_npcs_l2"] = float(
                np.linalg.norm(pa_t - pnpcs_gt[:, :, 0], axis=-1)[obj].mean())

    def fit(lab, co, pa) -> dict:
        outs = []
        for i in range(0, M, batch):
            sl = slice(i, i + batch)
            outs.append(net.fit_poses(pts[sl], lab[sl], co[sl], None if pa is None else pa[sl], scale[sl]))
        return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}

    lab0, co0, pa0 = nets[0]
    labn, con, pan = nets[infer_points]
    rungs = {"oracle": (lab_gt, naocs_gt, pnpcs_gt), "net labels + GT maps": (lab0, naocs_gt, pnpcs_gt),
             "GT labels + net maps": (lab_gt, co0, pa0), "net (all points)": (lab0, co0, pa0),
             f"net (infer_points={infer_points})": (labn, con, pan)}
    keys = ("S", "R", "R_median", "R_sym", "R_sym_median", "R_over90", "D", "C")
    res = {}
    for name, (lab, co, pa) in rungs.items():
        # background points (-1) have no map: label them as the network does for the oracle's sake (part 0)
        out = fit(np.where(lab < 0, 0, lab), co, pa)
        out["part_label"] = np.where(lab_gt < 0, -1, out["part_label"]) if name == "oracle" else out["part_label"]
        r = evaluate(data, _predictions(a, out, split, ds, name), split=split)
        res[name] = {k: round(float(r.summary[k]), 3) for k in keys if k in r.summary}
    out = {"rungs": res, "maps": maps}
    if train_clouds:  # the same per-point quality on training clouds: under- or over-fitting
        tr = load(data, "train")
        idx = np.linspace(0, len(tr) - 1, min(train_clouds, len(tr))).astype(int)
        b = {k: v[idx] for k, v in tr.arrays(["points", "part_label", "npcs"]).items()}
        tobj = b["part_label"] >= 0
        net.infer_points = 0
        with torch.no_grad():
            lo, co, _ = net.outputs(torch.from_numpy(b["points"]))
        at = torch.from_numpy(np.clip(b["part_label"], 0, None))[..., None, None].expand(-1, -1, 1, 3)
        co_t = co.gather(2, at).squeeze(2).double().numpy()
        out["maps_train"] = {"clouds": len(idx),
                             "seg_accuracy": float((lo.argmax(-1).numpy()[tobj] == b["part_label"][tobj]).mean()),
                             "naocs_l2": float(np.linalg.norm(co_t - b["npcs"], axis=-1)[tobj].mean())}
    return out


RUNGS = ("oracle", "net labels + GT maps", "GT labels + net maps", "net (all points)")


def digest(paths: list[Path]) -> str:
    """A Markdown table of ladder JSONs (this script's ``--out``): per file, each rung's S, R (mean and median), R sym,
    D and C averaged over the file's runs, then the per-point maps (label accuracy, NAOCS L2) of each inference mode
    and of the training clouds."""
    import statistics as st

    head = "| ladder | rung | S % | R | R median | R sym | R sym median | D | C |"
    lines = [head, "|---|---|--:|--:|--:|--:|--:|--:|--:|"]
    for path in paths:
        d = json.loads(Path(path).read_text())
        runs = list(d["runs"].values())
        name = f"{Path(str(d['data'])).name} {d['split']} ({len(runs)} runs)"
        rungs = [r for r in RUNGS if r in runs[0]["rungs"]] + [r for r in runs[0]["rungs"] if r not in RUNGS]
        for rung in rungs:
            m = {k: st.fmean(r["rungs"][rung][k] for r in runs) for k in ("S", "R", "R_median", "R_sym",
                                                                          "R_sym_median", "D", "C")}
            lines.append(f"| {name} | {rung} | {m['S']:.1f} | {m['R']:.1f} | {m['R_median']:.1f} | {m['R_sym']:.1f} | "
                         f"{m['R_sym_median']:.1f} | {m['D']:.1f} | {m['C']:.3f} |")
        maps = [(f"maps, {k.replace('infer_points=0', 'all points')}", [r["maps"][k] for r in runs])
                for k in runs[0]["maps"]]
        if "maps_train" in runs[0]:
            maps.append(("maps on training clouds, all points", [r["maps_train"] for r in runs]))
        for label, ms in maps:
            acc, l2 = st.fmean(m["seg_accuracy"] for m in ms), st.fmean(m["naocs_l2"] for m in ms)
            lines.append(f"| {name} | {label}: label accuracy {acc:.3f}, NAOCS L2 {l2:.3f} | | | | | | | |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--digest"]:  # python bench/diagnostics/npcs_diagnosis.py --digest LADDER.json ... [> table.md]
        try:
            print(digest([Path(a) for a in argv[1:]]), end="")
        except (OSError, ValueError, KeyError) as e:
            print(f"scapo: cannot digest the ladders ({type(e).__name__}: {e})", file=sys.stderr)
            return 2
        return 0
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--run", type=Path, action="append", required=True, help="a finished NPCS-style run; repeat")
    p.add_argument("--split", default="val", choices=["val", "test"])
    p.add_argument("--infer-points", type=int, default=256)
    p.add_argument("--out", type=Path, default=None, help="write the ladder (JSON) here")
    args = p.parse_args(argv)
    from scapo.errors import ScapoError
    from scapo.provenance import provenance

    try:
        t0 = time.perf_counter()
        rows = {str(r): ladder(args.data, r, args.split, args.infer_points) for r in args.run}
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    for run, lad in rows.items():
        print(f"# {run} ({args.split})")
        for name, s in lad["rungs"].items():
            print(f"  {name:28s} " + " ".join(f"{k}={v:.2f}" for k, v in s.items()))
        for mode, m in lad["maps"].items():
            print(f"  maps {mode:16s} " + " ".join(f"{k}={v:.4f}" for k, v in m.items()))
        if "maps_train" in lad:
            print("  maps train (all points) " + " ".join(f"{k}={v:.4f}" for k, v in lad["maps_train"].items()))
    if args.out:
        from scapo.data import load

        doc = {"split": args.split, "infer_points": args.infer_points, "runs": rows,
               "dataset_hash": load(args.data, args.split).dataset_hash, "data": str(args.data),
               "provenance": provenance(command="python bench/diagnostics/npcs_diagnosis.py "
                                        + " ".join(argv or sys.argv[1:])),
               "wall_s": round(time.perf_counter() - t0, 1)}
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=1, sort_keys=True))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
