"""Where a method's object frame holds and where it breaks, by the true articulation state (a ground-truth diagnosis
of predictions files already written; nothing is trained or predicted again).

    python bench/diagnostics/frame_by_state.py --data DATA --pred LABEL=PREDICTIONS.npz [--pred ...] --split test \\
        --out results/.../NAME [--bins 4]

Per file, on one split: the symmetry-aware object-frame consistency (:func:`scapo.eval.frames.frame_inliers`
against each sample's own and twin ground truths, :func:`scapo.eval.evaluator.object_frame_twins`); the share of
samples that agree through their own ground truth and through the twin; that share within each of ``--bins``
equal-count bins of the first joint's true state (its edges from the split, in degrees or metres); the share of views
whose slot 0 holds mostly true base points; the median angle of the samples outside the common frame to it; and, for
one-joint objects, the share against the bisector frame instead (:func:`joint_frames` at 0.5, with its twin's).
Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each file's sha256).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def state_bins(state: np.ndarray, bins: int) -> np.ndarray:
    """``(bins + 1,)`` edges of equal-count bins of ``state (M,)`` (its quantiles; the last edge inclusive)."""
    return np.quantile(np.asarray(state, dtype=np.float64), np.linspace(0.0, 1.0, bins + 1))


def by_state(inlier: np.ndarray, angle: np.ndarray, state: np.ndarray, edges: np.ndarray) -> dict:
    """The statistics of one file from :func:`scapo.eval.frames.frame_inliers`' ``inlier (M,)`` and ``angle (M, K)``
    (own ground truth first), the samples' first-joint state ``(M,)`` and the bins' ``edges``.

    Returns:
        ``sym`` (share of inliers), ``own`` and ``twin`` (inliers that agree through their own ground truth, or only
        through a twin), ``bins`` (per bin: ``lo``, ``hi``, ``samples``, ``sym``) and ``outlier_deg_median`` (the
        median of the outliers' smallest angle to the common frame; None without outliers).
    """
    inlier, angle, state = np.asarray(inlier, dtype=bool), np.asarray(angle, dtype=np.float64), np.asarray(state)
    own = inlier & (angle[:, 0] == angle.min(1))
    which = np.clip(np.searchsorted(edges, state, side="right") - 1, 0, len(edges) - 2)
    rows = [{"lo": float(edges[b]), "hi": float(edges[b + 1]), "samples": int((which == b).sum()),
             "sym": round(float(inlier[which == b].mean()), 4) if (which == b).any() else None}
            for b in range(len(edges) - 1)]
    out = angle.min(1)[~inlier]
    return {"sym": round(float(inlier.mean()), 4), "own": round(float(own.mean()), 4),
            "twin": round(float((inlier & ~own).mean()), 4), "bins": rows,
            "outlier_deg_median": round(float(np.median(out)), 2) if len(out) else None}


def joint_frames(part_pose: np.ndarray, lam: float, child: int = 1) -> np.ndarray:
    """``(M, 4, 4)``: the base part's pose (part 0 of ``part_pose (M, P, 4, 4)``) with its rotation turned ``lam`` of
    the way to part ``child``'s along their relative rotation (``R_base Exp(lam log(R_base^T R_child))``; 0: the base's
    frame, 0.5: the bisector of a one-joint object, 1: the child's), translation the base's. A frame on the whole
    articulated shape rather than on its base part sits near ``lam`` = 0.5."""
    from scipy.spatial.transform import Rotation

    P = np.asarray(part_pose, dtype=np.float64)
    Rb, Rc = P[:, 0, :3, :3], P[:, child, :3, :3]
    rel = Rotation.from_matrix(np.einsum("mji,mjk->mik", Rb, Rc)).as_rotvec()
    out = P[:, 0].copy()
    out[:, :3, :3] = np.einsum("mij,mjk->mik", Rb, Rotation.from_rotvec(lam * rel).as_matrix())
    return out


def main(argv=None) -> int:
    from scapo.bench.diagnosis import run_diagnosis
    from scapo.data import load
    from scapo.errors import PredictionError
    from scapo.eval.evaluator import object_frame_twins, twin_ground_truth
    from scapo.eval.frames import frame_inliers

    sys.path.insert(0, str(Path(__file__).resolve().parent))  # this folder's scripts import each other
    from frame_consistency import base_on_base
    cache = {}

    def score(a, p) -> dict:
        if "ds" not in cache:
            ds = load(a.data, a.split)
            cache.update(ds=ds, twins=object_frame_twins(ds), keys={k: i for i, k in enumerate(ds.keys())},
                         state=ds.arrays(["joint_state"])["joint_state"][:, 0].astype(np.float64),
                         revolute=int(ds.card["joint_type"][0]) == 0)  # SPEC: 0 revolute, 1 prismatic
            cache["edges"] = state_bins(cache["state"], a.bins)
            if len(ds.card["joint_type"]) == 1 and ds.card.get("symmetry"):  # the bisector's own and twin frames
                gt, tw = twin_ground_truth(ds)
                cache["bisector"] = np.stack([joint_frames(gt["part_pose"], 0.5),
                                              joint_frames(tw["part_pose"], 0.5)], 1)
            elif len(ds.card["joint_type"]) == 1:
                cache["bisector"] = joint_frames(ds.arrays(["part_pose"])["part_pose"], 0.5)[:, None]
        rows = np.flatnonzero(p.split == a.split)
        try:
            order = np.array([cache["keys"][(int(p.instance_id[i]), int(p.view_id[i]))] for i in rows], dtype=np.int64)
        except KeyError as e:
            raise PredictionError(f"predictions of {p.method!r} name sample {e.args[0]}, which the {a.split} split of "
                                  f"{a.data} lacks") from None
        inl, ang = frame_inliers(p.T_cam_obj[rows], cache["twins"][order])
        r = by_state(inl, ang, cache["state"][order], cache["edges"])
        if cache["revolute"]:
            for b in r["bins"]:
                b["lo"], b["hi"] = round(float(np.degrees(b["lo"])), 1), round(float(np.degrees(b["hi"])), 1)
        if "bisector" in cache:
            r["bisector_sym"] = round(float(frame_inliers(p.T_cam_obj[rows], cache["bisector"][order])[0].mean()), 4)
        return {**r, "samples": len(rows), "unit": "deg" if cache["revolute"] else "m",
                "slot0_on_base": round(base_on_base(Path(a.data), p, a.split), 4)}

    def check(a):
        return None if a.bins >= 1 else f"--bins must be at least 1, got {a.bins}"

    return run_diagnosis(argv, __doc__, "frame_by_state.py", score, render,
                         options=[("--bins", {"type": int, "default": 4})], check=check)


def render(a, rows: dict, card: dict) -> list[str]:
    """The Markdown lines: one row per file."""
    first = next(iter(rows.values()))
    heads = [f"{b['lo']:g} to {b['hi']:g} {first['unit']}" for b in first["bins"]]
    lines = [f"# Object-frame consistency by joint state ({Path(a.data).name}, {a.split})", "",
             "sym: share of samples within 15 deg of the common object-frame offset against their own or twin ground "
             "truth; own / twin: of those, through which. Then sym within equal-count bins of the first joint's true "
             "state. slot 0 on base: views whose slot 0 holds mostly true base points. outliers: median angle of the "
             "others to the common frame. bisector sym: the same share with the base's frame turned half way to the "
             "child's as the ground truth (one-joint objects): a frame on the whole articulated shape scores higher "
             "there than against the base.", "",
             "| predictions | samples | sym | own | twin | " + " | ".join(heads) + " | slot 0 on base | outliers deg | "
             "bisector sym |",
             "|:--|--:|--:|--:|--:|" + "--:|" * len(heads) + "--:|--:|--:|"]
    for label, r in rows.items():
        cells = " | ".join("-" if b["sym"] is None else f"{b['sym']:.2f}" for b in r["bins"])
        od = "-" if r["outlier_deg_median"] is None else f"{r['outlier_deg_median']:.0f}"
        bis = f"{r['bisector_sym']:.2f}" if "bisector_sym" in r else "-"
        lines.append(f"| {label} | {r['samples']} | {r['sym']:.2f} | {r['own']:.2f} | {r['twin']:.2f} | {cells} | "
                     f"{r['slot0_on_base']:.2f} | {od} | {bis} |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
