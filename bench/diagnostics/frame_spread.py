"""Where a method's object frame spreads: across the views of one instance (the frame depends on what the view shows)
or across instances (each shape gets its own frame). Reads the val predictions of ``scapo bench ladder`` or
``scapo bench compute`` cells and their dataset (nothing is trained or predicted again):

    python bench/diagnostics/frame_spread.py --data bench_work/ladder/data/laptop_paper_i60_v8_t16_s1 \\
        --cell scapo:5=bench_work/ladder/compute/b5/laptop/paper/scapo_s0_predictions.npz ... \\
        --out results/canonical_ladder/frame_spread

Per cell, from the object-frame offsets ``O = R_gt^T R_pred`` of its val samples (each folded to the declared
symmetric ground truth closest to the common offset, as the symmetry-aware scores do): the median angle of the
offsets to their chordal mean (what the frame consistency thresholds at 15 deg), the median angle of each sample to
its own instance's mean (view dependence) and the median angle of the instances' means to their mean (shape
dependence), with the number of val instances and samples.

The centre (issue 52's hypothesis that the visible points' mean moves the translation estimate with the viewpoint):
per sample, the predicted object origin ``c = R_gt^T (t_pred - t_gt)`` and the visible points' mean
``v = R_gt^T (mean(points) - t_gt)``, both in the true object frame (mm), minus their instance's mean over its views;
the median norm of each (how far the predicted centre and the visible mean move between views of one object), the
least-squares slope of the predicted centre's move on the visible mean's (1: the centre follows what is in view; 0:
it does not), and the rank correlation of a view's frame deviation from its instance's mean frame with its centre's
move (do the views whose centre moves also lose the frame?).

The articulation state (the views of one instance differ in joint state as well as in viewpoint: the datasets draw a
state per view): the component of each sample's deviation from the common offset about the first joint's axis (its
true axis in the object frame), its least-squares slope on the true joint state (1: the predicted base frame turns
with the child part, e.g. a laptop's lid; 0: it ignores the state) and the share of that component's variance the
state explains (R^2). ``--principal-reference``: a row of the same statistics for the frame read from the principal
axes of each view (:func:`scapo.nn.encoder.principal_frame`), each turned by the one of the 24 signed permutations
nearest the common offset (a perfect choice of hypothesis; ground truth used for that choice only): what the
principal frame gives at best. Writes ``<out>.{md,json}`` with provenance.

Errors: a missing dataset or predictions file, or a ``--cell`` not of the form ``LABEL=PATH``, end with a ``scapo:``
message and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script from anywhere in the checkout


def mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal mean of rotations ``(n, 3, 3)``."""
    U, _, Vt = np.linalg.svd(Rs.sum(0))
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def angles(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Angles (deg) between rotations ``A (n, 3, 3)`` and ``B`` (broadcast)."""
    B = np.broadcast_to(B, A.shape)
    return np.degrees(np.arccos(np.clip((np.einsum("nij,nij->n", A, B) - 1.0) / 2.0, -1.0, 1.0)))


def spread(data: Path, predictions: Path) -> dict:
    """The spread statistics of one cell's val predictions (see the module docstring)."""
    from scapo.data import load
    from scapo.eval import Predictions
    from scapo.eval.evaluator import object_frame_twins

    val = load(data, "val")
    arrays = val.arrays(["T_cam_obj", "points"])
    gt = arrays["T_cam_obj"]
    keys = {k: i for i, k in enumerate(val.keys())}
    p = Predictions.load(predictions)
    rows = [i for i in range(len(p)) if str(p.split[i]) == "val"]
    inst = np.array([int(p.instance_id[i]) for i in rows])
    order = np.array([keys[(int(p.instance_id[i]), int(p.view_id[i]))] for i in rows])
    O = np.einsum("nji,njk->nik", gt[order][:, :3, :3], p.T_cam_obj[rows][:, :3, :3].astype(np.float64))
    M = mean_rotation(O)
    twins = object_frame_twins(val)[order]  # (n, K, 4, 4): the declared symmetric ground truths
    if twins.shape[1] > 1:  # each sample against the declared symmetric ground truth that fits the common offset best
        pred_R = p.T_cam_obj[rows][:, :3, :3].astype(np.float64)
        cands = np.stack([np.einsum("nji,njk->nik", twins[:, k, :3, :3], pred_R) for k in range(twins.shape[1])])
        d = np.stack([angles(c, M) for c in cands])
        O = cands[d.argmin(0), np.arange(len(O))]
        M = mean_rotation(O)
    Rg, tg = gt[order][:, :3, :3], gt[order][:, :3, 3]
    centre = np.einsum("nji,nj->ni", Rg, p.T_cam_obj[rows][:, :3, 3].astype(np.float64) - tg)
    visible = np.einsum("nji,nj->ni", Rg, arrays["points"][order].astype(np.float64).mean(1) - tg)
    return {**spread_stats(O, inst), **centre_stats(O, centre, visible, inst), **_state(val, order, Rg, O)}


def _state(val, order: np.ndarray, Rg: np.ndarray, O: np.ndarray) -> dict:
    """:func:`state_stats` of the first joint of the samples ``order`` of the split ``val`` ({} without joints)."""
    if not len(val.card.get("joint_type", ())):
        return {}
    a = val.arrays(["joint_state", "joint_axis"])
    axis = np.einsum("nji,nj->ni", Rg, a["joint_axis"][order][:, 0].astype(np.float64))  # object frame
    return state_stats(O, axis, a["joint_state"][order][:, 0].astype(np.float64))


def state_stats(O: np.ndarray, axis: np.ndarray, state: np.ndarray) -> dict:
    """The articulation-state statistics (see the module docstring) of offsets ``O (n, 3, 3)`` (``R_gt^T R_pred``)
    with the first joint's true axis ``(n, 3)`` in the object frame and its state ``(n,)`` (rad, or m for a prismatic
    joint: then the slope is in deg per m)."""
    from scipy.spatial.transform import Rotation

    M = mean_rotation(O)
    dev = Rotation.from_matrix(np.einsum("nij,kj->nik", O, M)).as_rotvec()  # O M^T, object frame
    axis = axis / np.linalg.norm(axis, axis=1, keepdims=True).clip(1e-12)
    about = np.degrees((dev * axis).sum(1))
    x = np.degrees(state) - np.degrees(state).mean()
    slope = float((x * (about - about.mean())).sum() / max((x * x).sum(), 1e-18))
    var = float(((about - about.mean()) ** 2).sum())
    r2 = 1.0 - float(((about - about.mean() - slope * x) ** 2).sum()) / var if var > 0 else float("nan")
    return {"about_joint_on_state_slope": round(slope, 2), "about_joint_state_r2": round(r2, 2)}


def principal_reference(data: Path) -> dict:
    """The spread statistics of the principal-axes frame of every val view with a perfect choice among the 24
    signed permutations (see the module docstring)."""
    import torch

    from scapo.data import load
    from scapo.nn.encoder import principal_frame
    from scapo.ops.groups import rotation_group

    val = load(data, "val")
    arrays = val.arrays(["T_cam_obj", "points"])
    Rg = arrays["T_cam_obj"][:, :3, :3]
    R = principal_frame(torch.as_tensor(np.asarray(arrays["points"], dtype=np.float64))).numpy()
    O = np.einsum("nji,njk->nik", Rg, R)
    G = np.asarray(rotation_group("O"), dtype=np.float64)
    cand = np.einsum("nij,kjl->nkil", O, G)  # (n, 24, 3, 3): O G_k
    best = None
    for ref in O:  # the common offset: the reference that the most samples reach within 15 deg
        d = np.degrees(np.arccos(np.clip((np.einsum("nkij,ij->nk", cand, ref) - 1.0) / 2.0, -1.0, 1.0)))
        share = float((d.min(1) < 15.0).mean())
        if best is None or share > best[0]:
            best = (share, cand[np.arange(len(O)), d.argmin(1)])
    O = best[1]
    inst = val.manifest["instance_id"].to_numpy()
    return {**spread_stats(O, inst), "within_15deg_of_common": round(best[0], 2),
            **_state(val, np.arange(len(O)), Rg, O)}


def centre_stats(O: np.ndarray, centre: np.ndarray, visible: np.ndarray, inst: np.ndarray) -> dict:
    """The centre statistics (see the module docstring) of offsets ``O (n, 3, 3)``, predicted centres and visible
    means ``(n, 3)`` in the true object frame (metres), of samples of instances ``inst (n,)``."""
    from scipy.stats import spearmanr

    dc, dv, dev = np.zeros_like(centre), np.zeros_like(visible), np.zeros(len(O))
    for i in np.unique(inst):
        m = inst == i
        dc[m], dv[m] = centre[m] - centre[m].mean(0), visible[m] - visible[m].mean(0)
        dev[m] = angles(O[m], mean_rotation(O[m]))
    slope = float((dc * dv).sum() / max((dv * dv).sum(), 1e-18))
    moved = np.linalg.norm(dc, axis=1)
    rho = spearmanr(dev, moved).statistic if len(O) > 2 and moved.std() > 0 and dev.std() > 0 else float("nan")
    return {"median_centre_move_mm": round(1000 * float(np.median(moved)), 1),
            "median_visible_move_mm": round(1000 * float(np.median(np.linalg.norm(dv, axis=1))), 1),
            "centre_on_visible_slope": round(slope, 2), "frame_vs_centre_rank_corr": round(float(rho), 2)}


def spread_stats(O: np.ndarray, inst: np.ndarray) -> dict:
    """The statistics of offsets ``O (n, 3, 3)`` of samples of instances ``inst (n,)`` (see the module docstring)."""
    M = mean_rotation(O)
    within, means = [], []
    for i in np.unique(inst):
        Mi = mean_rotation(O[inst == i])
        means.append(Mi)
        within += list(angles(O[inst == i], Mi))
    means = np.stack(means)
    return {"median_to_common_deg": round(float(np.median(angles(O, M))), 1),
            "median_within_instance_deg": round(float(np.median(within)), 1),
            "median_instance_means_to_common_deg": round(float(np.median(angles(means, mean_rotation(means)))), 1),
            "instances": int(len(means)), "samples": int(len(O))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True, help="the cells' dataset folder (its val split is read)")
    ap.add_argument("--cell", action="append", default=[], help="LABEL=PREDICTIONS.npz (repeat)")
    ap.add_argument("--out", type=Path, required=True, help="output stem: writes <out>.md and <out>.json")
    ap.add_argument("--principal-reference", action="store_true", help="add a row for the principal axes of each view "
                    "with a perfect choice of signed permutation (what the principal frame gives at best)")
    args = ap.parse_args(argv)
    from scapo.errors import ScapoError
    from scapo.files import atomic_write_text, write_json
    from scapo.provenance import provenance

    try:
        cells = []
        for c in args.cell:
            label, eq, path = c.partition("=")
            if not eq or not label or not path:
                raise ScapoError(f"--cell {c!r} is not LABEL=PREDICTIONS.npz")
            cells.append((label, Path(path)))
        if not cells and not args.principal_reference:
            raise ScapoError("give at least one --cell LABEL=PREDICTIONS.npz (or --principal-reference)")
        rows = {label: spread(args.data, path) for label, path in cells}
        if args.principal_reference:
            rows["principal axes, best of 24 (reference)"] = principal_reference(args.data)
    except (ScapoError, OSError, KeyError) as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    prov = provenance(command="bench/diagnostics/frame_spread.py", dataset=args.data.name,
                      cells={label: str(path) for label, path in cells})
    md = ["# Where the object frame spreads (val)", "",
          "Median angles (deg) of the val samples' object-frame offsets (folded to the declared symmetric ground "
          "truth): to their common mean; to their own instance's mean (views of one object: view dependence); and of "
          "the instances' means to their common mean (shape dependence).", "",
          "Centre: how far (median, mm) the predicted object origin and the visible points' mean move between the "
          "views of one object (in the true object frame), the slope of the first on the second (1: the centre follows "
          "the visible points), and the rank correlation of a view's frame deviation with its centre's move.", "",
          "State: the views of one object differ in joint state too; the slope of each view's deviation about the "
          "first joint's axis on the joint state (deg per deg; 1: the base frame turns with the child part) and the "
          "share of that deviation's variance the state explains (R^2). The principal-axes reference row (when "
          "present) is the frame read from each view's principal axes, with the signed permutation nearest the common "
          "offset chosen by the ground truth: what a principal frame gives at best.", "",
          "| cell | to common | within instance | instance means | centre move mm | visible-mean move mm | "
          "centre-on-visible slope | frame-vs-centre corr | about-joint slope on state | state R^2 | instances | "
          "samples |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    md += [f"| {k} | {v['median_to_common_deg']} | {v['median_within_instance_deg']} | "
           f"{v['median_instance_means_to_common_deg']} | {v.get('median_centre_move_mm', '-')} | "
           f"{v.get('median_visible_move_mm', '-')} | {v.get('centre_on_visible_slope', '-')} | "
           f"{v.get('frame_vs_centre_rank_corr', '-')} | {v.get('about_joint_on_state_slope', '-')} | "
           f"{v.get('about_joint_state_r2', '-')} | {v['instances']} | {v['samples']} |" for k, v in rows.items()]
    md += ["", f"Provenance: commit {prov.get('commit')}, dataset `{args.data.name}`; written by "
           "`bench/diagnostics/frame_spread.py`.", ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out.with_suffix(".md"), "\n".join(md))
    write_json(args.out.with_suffix(".json"), {"cells": rows, "provenance": prov})
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
