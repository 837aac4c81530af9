"""Would the base part's principal axes give one canonical frame? (issue 52; :mod:`scapo.steps.base_frame`)

Two measurements on a ladder rung's dataset and trained SCAPO runs (nothing is trained):

1. The reference (ground truth only, no method): the share of the val views whose principal axes of (a) the whole
   object cloud, (b) the base part's points, (c) the child part's points agree with one frame within 15 deg, after
   each view's axes take the one of the 24 signed permutations nearest a reference view's (the best reference of all
   views). This is what a frame read from those points could give at best.
2. The snap (``scapo predict --option base_frame=principal``) of each run, with the base points from: ``network``
   (the run's own part 0: the method as it would run), and two diagnoses that use ground truth and are **not**
   method rows: ``gt`` (the true base points) and ``gt-as-network`` (the true part that holds most of the network's
   part-0 points: the true segmentation with the network's choice of which part is its base). Symmetry-aware object-
   frame consistency on val before and after, as ``scapo bench ladder`` computes it, with the offset's support on
   the training views. Each source is scored with the base in slot 0 and, where it differs, in the slot
   ``base_slot=auto`` chooses on the training views (:func:`scapo.steps.base_frame.choose_base_slot`; for
   ``gt-as-network``, the true part holding most of that slot's points is the base).

    python bench/diagnostics/base_frame_snap.py --data DATA --run LABEL=RUN [--run ...] --out \\
        results/canonical_ladder/base_snap

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, runs' identities).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def axes_consistency(R_gt: np.ndarray, E: np.ndarray, inlier_deg: float = 15.0) -> tuple[float, float]:
    """Share of views (and their median angle, deg) whose axes ``E (V, 3, 3)``, in the true object frame, agree with
    one frame within ``inlier_deg`` after each view's best signed permutation
    (:func:`scapo.steps.base_frame.fit_base_offset` with the true rotations ``R_gt (V, 3, 3)`` as the "network",
    every view tried as the reference)."""
    from scapo.steps.base_frame import fit_base_offset

    _, share, angle = fit_base_offset(R_gt, E, inlier_deg, candidates=len(E))
    return share, float(np.median(angle))


def _as_network(net_label: np.ndarray, gt_label: np.ndarray, slot: int = 0) -> np.ndarray:
    """The true segmentation, with the true part holding most of the network's slot-``slot`` points called part 0
    (every other true part 1, background -1)."""
    base = np.array([max(_majority(n == slot, g), 0) for n, g in zip(net_label, gt_label)])
    return np.where(gt_label == base[:, None], 0, np.where(gt_label >= 0, 1, -1))


def _majority(in_slot: np.ndarray, gt: np.ndarray) -> int:
    """The true part (>= 0) holding most of one view's points where ``in_slot (N,)`` bool; -1 if none."""
    sel = in_slot & (gt >= 0)
    return int(np.bincount(gt[sel]).argmax()) if sel.any() else -1


def _as_slot(label: np.ndarray, slot: int) -> np.ndarray:
    """Labels with the base as 0 and the rest as 1 (-1 background) renumbered so that the base is ``slot``."""
    return np.where(label == 0, slot, np.where(label >= 0, 1 if slot == 0 else 0, -1))


def _base_labels(src: str, pred: dict, gt: dict, slot: int) -> np.ndarray:
    """The labels whose slot ``slot`` is the base, from source ``src``: the network's own, the true segmentation
    (``gt``) or the true one with the network's choice of base (``gt-as-network``)."""
    if src == "network":
        return pred["part_label"]
    base = gt["part_label"].clip(-1, 1) if src == "gt" else _as_network(pred["part_label"], gt["part_label"], slot)
    return _as_slot(base, slot)


def main(argv=None) -> int:
    from scapo.data import load
    from scapo.eval.evaluator import object_frame_twins
    from scapo.eval.frames import frame_consistency
    from scapo.methods import load_run
    from scapo.provenance import provenance
    from scapo.steps.base_frame import base_axes, choose_base_slot, fit_base_offset, rotation_dispersion, snap_to_base

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--run", action="append", default=[], help="LABEL=RUN (a trained SCAPO run folder)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    for f in [a.data] + [r.partition("=")[2] for r in a.run]:
        if not Path(f).is_dir():
            print(f"scapo: {f} is not a folder; give a dataset (--data) and trained runs (--run LABEL=RUN)",
                  file=sys.stderr)
            return 2
    train, val = load(a.data, "train"), load(a.data, "val")
    A, B = train.arrays(), val.arrays()
    gt_T = object_frame_twins(val)  # (M, K, 4, 4): the declared symmetric ground truths
    R_gt = np.asarray(B["T_cam_obj"], dtype=np.float64)[:, :3, :3]
    lines = [f"# The base part's principal axes as the canonical frame ({Path(a.data).name}, val, "
             f"{len(B['points'])} views)", "",
             "Reference (ground truth, no method): share of val views whose axes agree with one frame within 15 deg "
             "(best signed permutation per view), and the median angle to it.", "",
             "| points | share within 15 deg | median deg |", "|:--|--:|--:|"]
    ref = {}
    for name, lab in (("whole object", np.where(B["part_label"] >= 0, 0, 1)), ("base part (0)", B["part_label"]),
                      ("child part (1)", np.where(B["part_label"] == 1, 0, 1))):
        E, ok = base_axes(B["points"], lab)
        ref[name] = axes_consistency(R_gt[ok], E[ok])
        lines.append(f"| {name} | {ref[name][0]:.2f} | {ref[name][1]:.1f} |")
    lines += ["", "Snap of each run's one-pass prediction (symmetry-aware object-frame consistency on val; `network` "
              "is the method, `gt` and `gt-as-network` are diagnoses with ground-truth base points):", "",
              "| run | base points | base slot | offset support (train) | frame cons. sym before | after | "
              "median snap deg |", "|:--|:--|:--|--:|--:|--:|--:|"]
    rows, slots_lines = [], []
    for spec in a.run:
        label, _, run = spec.partition("=")
        m = load_run(run, refine_steps=0)
        ot, ov = m.predict_points(A["points"]), m.predict_points(B["points"])
        before = frame_consistency(np.asarray(ov["T_cam_obj"]), gt_T)
        auto, disp = choose_base_slot(np.asarray(ot["part_pose"]))
        is_base = [float(np.mean([_majority(n, g) == 0 for n, g in zip(ot["part_label"] == s, A["part_label"])]))
                   for s in range(len(disp))]
        slots_lines.append(f"| {label} | {' / '.join(f'{d:.3f}' for d in disp)} | {auto} | "
                           f"{' / '.join(f'{b:.2f}' for b in is_base)} |")
        slots = [0] + ([auto] if auto != 0 else [])
        for src in ("network", "gt", "gt-as-network"):
            for slot in slots:
                # the base's points as slot `slot` of the labels; the network's pose of `slot` is the reference
                lt, lv = _base_labels(src, ot, A, slot), _base_labels(src, ov, B, slot)
                E, ok = base_axes(A["points"], lt, slot=slot)
                O, support, _ = fit_base_offset(np.asarray(ot["part_pose"])[ok, slot, :3, :3], E[ok])
                sv = snap_to_base(B["points"], {**ov, "part_label": lv}, O, slot=slot)
                after = frame_consistency(sv["T_cam_obj"], gt_T)
                tag = f"{slot}" + (" (auto)" if slot == auto else "")
                rows.append({"run": label, "run_path": run, "base_points": src, "slot": slot, "auto_slot": auto,
                             "dispersion": disp.round(4).tolist(), "support": support, "before": before,
                             "after": after, "snap_deg_median": float(np.median(sv["base_snap_deg"])),
                             "identity": {k: m.predictor.identity.get(k) for k in ("dataset_hash", "category")}})
                lines.append(f"| {label} | {src} | {tag} | {support:.2f} | {before:.2f} | {after:.2f} | "
                             f"{np.median(sv['base_snap_deg']):.1f} |")
                print(lines[-1], flush=True)
    cmd = "python bench/diagnostics/base_frame_snap.py " + " ".join(sys.argv[1:] if argv is None else argv)
    lines += ["", "Which slot is the base (`base_slot=auto`): the spread of each slot's predicted rotations over the "
              "training views (:func:`scapo.steps.base_frame.choose_base_slot`; 0 = one rotation), the slot it "
              "chooses, and, as a diagnosis with ground truth, the share of training views where each slot's points "
              "are mostly the true base (true base rotations spread "
              f"{rotation_dispersion(np.asarray(A['T_cam_obj'])[:, :3, :3]):.3f}):", "",
              "| run | spread per slot | chosen slot | slot is the true base (train views) |", "|:--|:--|--:|:--|",
              *slots_lines]
    lines += ["", f"Written by `{cmd}`."]
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    out.with_suffix(".json").write_text(json.dumps({
        "command": cmd, "dataset": str(a.data), "dataset_hash": val.card.get("dataset_hash"),
        "reference": {k: {"share": v[0], "median_deg": v[1]} for k, v in ref.items()}, "rows": rows,
        "provenance": provenance()}, indent=1, default=str))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
