"""Where a method's part split breaks next to its joints, and what the hinge re-split recovers (issue 52;
:mod:`scapo.steps.hinge`).

From a dataset and predictions files of any methods (``scapo predict`` output; nothing is trained or predicted here),
on one split (val by default), per predictions file:

- ``own``: S of the method's labels; ``hinge``: S after :func:`scapo.steps.hinge.hinge_prediction` on the method's
  own labels, axes and pivots (what ``--option hinge=true`` gives);
- diagnoses with ground truth (**not** method rows): the re-split started from the true joint (axis and pivot), from
  the predicted axis and the true pivot, and from the true axis and the predicted pivot (the fit moves the pivot in
  the plane normal to the axis, never the axis), each from the method's labels after the evaluator's part matching;
  and the re-split's own ceiling (the true joint and the true labels);
- where the errors lie: the share of each true part's points the method gives to another part, and the share of
  mislabelled points within 0.1 bounding-box diagonals of the (first) true joint line;
- the pivot's distance to the true joint line (the nearest true joint, in bounding-box diagonals), before and after.

    python bench/diagnostics/hinge_diagnosis.py --data DATA --pred LABEL=PREDICTIONS.npz [--pred ...] --out \\
        results/.../NAME

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each file's sha256).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def _line_dist(p: np.ndarray, pivot: np.ndarray, axis: np.ndarray) -> float:
    a = axis / np.linalg.norm(axis)
    w = p - pivot
    return float(np.linalg.norm(w - (w @ a) * a))


def _S(lab: np.ndarray, gt: np.ndarray, P: int) -> float:
    from scapo.eval.metrics import match_parts, relabel, segmentation_iou

    return float(np.nanmean(segmentation_iou(relabel(lab, match_parts(lab, gt, P)), gt, P)) * 100)


def score(B: dict, pred, split: str) -> dict:
    """The rows of one predictions object ``pred`` (:class:`~scapo.eval.predictions.Predictions`) on the split's
    arrays ``B`` (ground truth): see the module docstring."""
    from scapo.eval.metrics import match_parts, relabel
    from scapo.steps.hinge import hinge_fit, hinge_prediction

    sel = np.asarray(pred.split) == split
    key = {(int(i), int(v)): k for k, (i, v) in enumerate(zip(pred.instance_id[sel], pred.view_id[sel]))}
    idx = np.array([key[(int(i), int(v))] for i, v in zip(B["instance_id"], B["view_id"])])
    lab = np.asarray(pred.part_label)[sel][idx]
    o = {"part_label": lab, "joint_axis": np.asarray(pred.joint_axis)[sel][idx],
         "joint_pivot": np.asarray(pred.joint_pivot)[sel][idx]}
    jt, jp = np.asarray(pred.joint_type)[sel][idx][0], np.asarray(pred.joint_parts)[sel][idx][0]
    h = hinge_prediction(B["points"], o, jt, jp)
    gt_all, P = B["part_label"], int(B["part_label"].max()) + 1
    rows = {k: [] for k in ("own", "hinge", "true joint", "own axis, true pivot", "true axis, own pivot",
                            "ceiling (true joint, true labels)")}
    wrong_part, near, piv0, piv1 = np.zeros((P, 2)), [0, 0], [], []
    gjt, gjp = B["joint_type"][0], B["joint_parts"][0]
    for m in range(len(idx)):
        gt, pts = gt_all[m], B["points"][m]
        rows["own"].append(_S(lab[m], gt, P))
        rows["hinge"].append(_S(h["part_label"][m], gt, P))
        matched = relabel(lab[m], match_parts(lab[m], gt, P))
        for name, start in (("true joint", matched), ("own axis, true pivot", matched),
                            ("true axis, own pivot", matched), ("ceiling (true joint, true labels)", gt)):
            new = start.copy()
            for j in range(len(gjt)):
                if int(gjt[j]) != 0:
                    continue
                # the predicted joint paired with this true one: the nearest line (joints are unordered slots)
                k = int(np.argmin([_line_dist(o["joint_pivot"][m, q], B["joint_pivot"][m, j], B["joint_axis"][m, j])
                                   for q in range(o["joint_axis"].shape[1])]))
                axis = o["joint_axis"][m, k] if name == "own axis, true pivot" else B["joint_axis"][m, j]
                pivot = o["joint_pivot"][m, k] if name == "true axis, own pivot" else B["joint_pivot"][m, j]
                new, _ = hinge_fit(pts, new, pivot, axis, int(gjp[j, 0]), int(gjp[j, 1]))
            rows[name].append(_S(new, gt, P))
        ok = gt >= 0
        for p in range(P):
            wrong_part[p] += [np.count_nonzero(ok & (gt == p) & (matched != p)), np.count_nonzero(ok & (gt == p))]
        err = ok & (matched != gt)
        if len(gjt):
            a = B["joint_axis"][m, 0] / np.linalg.norm(B["joint_axis"][m, 0])
            w = pts - B["joint_pivot"][m, 0]
            d = np.linalg.norm(w - (w @ a)[:, None] * a, axis=1) / B["bbox_diag"][m]
            near[0] += np.count_nonzero(err & (d < 0.1))
            near[1] += np.count_nonzero(err)
        for j in range(len(gjt)):
            dd = [[_line_dist(pv[m, q], B["joint_pivot"][m, j], B["joint_axis"][m, j]) / B["bbox_diag"][m]
                   for q in range(o["joint_axis"].shape[1])] for pv in (o["joint_pivot"], h["joint_pivot"])]
            k = int(np.argmin(dd[0]))
            piv0.append(dd[0][k])
            piv1.append(dd[1][k])
    res = {name: {"S_mean": round(float(np.mean(v)), 2), "S_median": round(float(np.median(v)), 2)}
           for name, v in rows.items()}
    res["hinge"]["better_share"] = round(float(np.mean(np.array(rows["hinge"]) > np.array(rows["own"]))), 3)
    res["errors"] = {"part_given_to_another": [round(float(a / max(b, 1)), 3) for a, b in wrong_part],
                     "errors_within_0.1_diag_of_joint": round(near[0] / max(near[1], 1), 3),
                     "pivot_line_diag_median": [round(float(np.median(piv0)), 4), round(float(np.median(piv1)), 4)]}
    res["views"] = int(len(idx))
    return res


def main(argv=None) -> int:
    from scapo.bench.diagnosis import diagnosis_args, finish_diagnosis
    from scapo.data import load
    from scapo.errors import ScapoError
    from scapo.eval.predictions import Predictions

    parsed = diagnosis_args(argv, __doc__.split("\n\n")[0])
    if parsed is None:
        return 2
    a, preds = parsed
    try:
        B = load(a.data, a.split).arrays()
        rows = {label: score(B, Predictions.load(f), a.split) for label, _, f in preds}
    except (ScapoError, KeyError) as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    card = load(a.data, a.split).card
    cmd = "python bench/diagnostics/hinge_diagnosis.py " + " ".join(sys.argv[1:] if argv is None else argv)
    lines = [f"# The part split next to the joints, and the hinge re-split ({Path(a.data).name}, {a.split}, "
             f"{next(iter(rows.values()))['views']} views)", "",
             "S (%, mean / median over views, the evaluator's per-view part matching). `own`: the method's labels; "
             "`hinge`: `--option hinge=true` (its own joint, no ground truth). The next four columns are diagnoses "
             "with ground truth, not method rows: the re-split started from the true joint; from the predicted axis "
             "and the true pivot; from the true axis and the predicted pivot (the fit moves the pivot, never the "
             "axis); and the re-split's ceiling (true joint, true labels).", "",
             "| predictions | own | hinge | hinge better in | true joint | own axis, true pivot | true axis, own pivot "
             "| ceiling |", "|:--|--:|--:|--:|--:|--:|--:|--:|"]
    f = "{S_mean:.1f} / {S_median:.1f}".format
    for label, r in rows.items():
        lines.append(f"| {label} | {f(**r['own'])} | {f(**{k: r['hinge'][k] for k in ('S_mean', 'S_median')})} | "
                     f"{r['hinge']['better_share']:.2f} | {f(**r['true joint'])} | {f(**r['own axis, true pivot'])} | "
                     f"{f(**r['true axis, own pivot'])} | {f(**r['ceiling (true joint, true labels)'])} |")
    lines += ["", "Where the method's errors lie (its own labels), and the pivot's distance to the true joint line "
              "(median, bounding-box diagonals) before and after the re-split:", "",
              "| predictions | share of each true part given to another | errors within 0.1 diag of the joint | "
              "pivot to joint line, own -> hinge |", "|:--|:--|--:|:--|"]
    for label, r in rows.items():
        e = r["errors"]
        lines.append(f"| {label} | {' / '.join(f'{v:.3f}' for v in e['part_given_to_another'])} | "
                     f"{e['errors_within_0.1_diag_of_joint']:.3f} | {e['pivot_line_diag_median'][0]:.3f} -> "
                     f"{e['pivot_line_diag_median'][1]:.3f} |")
    return finish_diagnosis(a, preds, lines, rows, card, cmd)


if __name__ == "__main__":
    raise SystemExit(main())
