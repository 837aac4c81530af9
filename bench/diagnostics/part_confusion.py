"""Which parts a method's segmentation confuses, and at which joint states: a diagnosis on predictions files already
written (no training).

For each file, on one split (val by default): the one assignment of the method's part slots to the true parts that
gives the best mean IoU over the split (as the evaluator's S), then

- the confusion matrix: of each true part's points, the share each (assigned) predicted part got;
- per joint, the IoU of its child part in views binned by the joint's true state (``--bins`` degrees for revolute
  joints, metres for prismatic ones);
- for parts exchanged by a mirror of the object (two children of one parent, e.g. the eyeglasses' temples), the mean
  IoU of the two children as assigned and with the two exchanged in each view, and the share of views where the
  exchange fits better: a view-level swap (a frame turned by a half turn) reads high there, points mixed within views
  low in both.

    python bench/diagnostics/part_confusion.py --data DATA --pred LABEL=PREDICTIONS.npz [--pred ...] --out \\
        results/.../NAME \
        [--bins 0,20,50,180]

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each file's sha256).
"""

from __future__ import annotations

import itertools
from pathlib import Path


def iou(a, b):
    """Per-view IoU ``(M,)`` of two boolean masks ``(M, N)`` (0 where both are empty)."""
    import numpy as np

    return (a & b).sum(1) / np.maximum((a | b).sum(1), 1)


def best_assignment(pred, labels, num_parts: int) -> tuple[tuple[int, ...], float]:
    """The slot of each true part (a permutation) with the best mean IoU over views and parts, and that mean."""
    import numpy as np

    best = None
    for perm in itertools.permutations(range(num_parts)):
        m = float(np.mean([iou(pred == perm[p], labels == p).mean() for p in range(num_parts)]))
        if best is None or m > best[1]:
            best = (perm, m)
    return best


def confusion(pred, labels, perm, num_parts: int):
    """``(P, P)`` shares: row ``p`` (true part), column ``q`` (the slot assigned to part ``q``)."""
    import numpy as np

    C = np.array([[((labels == p) & (pred == perm[q])).sum() for q in range(num_parts)] for p in range(num_parts)],
                 dtype=np.float64)
    return C / np.maximum(C.sum(1, keepdims=True), 1)


def diagnose(data: Path, preds, split: str, bins: list[float]) -> dict:
    """The rows (see the module docstring) for one predictions file."""
    import numpy as np

    from scapo.data import load
    from scapo.steps.hinge import prediction_arrays

    card = load(data, split).card
    rows = np.flatnonzero(preds.split == split)
    gt = prediction_arrays(data, preds, ("part_label", "joint_state"))
    return score_labels(preds.part_label[rows], gt["part_label"][rows], gt["joint_state"][rows], card, bins)


def score_labels(pred, labels, state, card: dict, bins: list[float]) -> dict:
    """The rows (see the module docstring) of part labels ``pred (V, N)`` int (-1: none) against the true ``labels
    (V, N)`` int and joint states ``state (V, J)`` (rad or m) of a dataset whose card is ``card``; ``bins``: the
    joint-state bin edges (deg for revolute joints, m for prismatic ones). Also used for stage 2's pseudo-labels on
    the training split (``bench/diagnostics/pseudo_label_confusion.py``)."""
    import numpy as np

    P = len(card["part_names"])
    perm, miou = best_assignment(pred, labels, P)
    out = {"views": int(len(pred)), "assignment": list(perm), "mean_iou": round(miou, 4),
           "part_iou": [round(float(iou(pred == perm[p], labels == p).mean()), 4) for p in range(P)],
           "confusion": confusion(pred, labels, perm, P).round(4).tolist(), "by_state": {}, "mirror_pairs": []}
    jt, jp = card["joint_type"], card["joint_parts"]
    for j, ((_, child), t) in enumerate(zip(jp, jt)):
        s = np.degrees(np.abs(state[:, j])) if int(t) == 0 else np.abs(state[:, j])
        child_iou = iou(pred == perm[child], labels == child)
        out["by_state"][str(j)] = [
            {"from": lo, "to": hi, "views": int(((s >= lo) & (s < hi)).sum()),
             "child_iou": round(float(child_iou[(s >= lo) & (s < hi)].mean()), 4) if ((s >= lo) & (s < hi)).any()
             else None} for lo, hi in zip(bins[:-1], bins[1:])]
    for (j1, (p1, c1)), (j2, (p2, c2)) in itertools.combinations(list(enumerate(jp)), 2):
        if p1 != p2 or jt[j1] != jt[j2]:
            continue
        kept = 0.5 * (iou(pred == perm[c1], labels == c1) + iou(pred == perm[c2], labels == c2))
        swapped = 0.5 * (iou(pred == perm[c2], labels == c1) + iou(pred == perm[c1], labels == c2))
        out["mirror_pairs"].append({"children": [int(c1), int(c2)], "kept": round(float(kept.mean()), 4),
                                    "exchanged": round(float(swapped.mean()), 4),
                                    "best_of_two": round(float(np.maximum(kept, swapped).mean()), 4),
                                    "views_exchange_fits_better": round(float((swapped > kept).mean()), 4)})
    return out


def bin_edges(text: str) -> list[float] | None:
    """``--bins`` as two or more increasing numbers, or None."""
    try:
        bins = [float(b) for b in text.split(",")]
    except ValueError:
        return None
    return bins if len(bins) >= 2 and all(b < c for b, c in zip(bins[:-1], bins[1:])) else None


def main(argv=None) -> int:
    from scapo.bench.diagnosis import run_diagnosis

    return run_diagnosis(argv, __doc__, "part_confusion.py",
                         lambda a, p: diagnose(Path(a.data), p, a.split, bin_edges(a.bins)), render,
                         [("--bins", {"default": "0,20,50,180", "help": "joint-state bin edges (deg or m)"})],
                         lambda a: None if bin_edges(a.bins) else (f"--bins {a.bins!r}: give two or more increasing "
                                                                   "numbers, e.g. 0,20,50,180"))


def render(a, rows: dict, card: dict) -> list[str]:
    """The Markdown lines: per file, the confusion, the child IoU by state and the mirror pairs."""
    names = card["part_names"]
    lines = [f"# Part confusion ({Path(a.data).name}, {a.split})", "",
             "Slots assigned to the true parts by the best mean IoU over the split. Confusion: of each true part's "
             "points, the share each assigned part got (rows: true). Child IoU by the joint's true state. Mirror "
             "pairs: two children of one parent, mean IoU as assigned, exchanged in each view, the better of the two "
             "per view, and the share of views where the exchange fits better.", ""]
    for label, r in rows.items():
        lines += [f"## {label}", "", f"{r['views']} views; mean IoU {r['mean_iou']:.3f}; per part "
                  + ", ".join(f"{n} {v:.3f}" for n, v in zip(names, r["part_iou"])), "",
                  "| true \\ predicted | " + " | ".join(names) + " |", "|:--|" + "--:|" * len(names)]
        lines += [f"| {n} | " + " | ".join(f"{v:.2f}" for v in row) + " |" for n, row in zip(names, r["confusion"])]
        lines += ["", "| joint | state bin | views | child IoU |", "|:--|:--|--:|--:|"]
        for j, cells in r["by_state"].items():
            for c in cells:
                v = "-" if c["child_iou"] is None else f"{c['child_iou']:.3f}"
                lines.append(f"| {card['joint_names'][int(j)] if card.get('joint_names') else j} | "
                             f"{c['from']:g}-{c['to']:g} | {c['views']} | {v} |")
        for m in r["mirror_pairs"]:
            lines += ["", f"Mirror pair {names[m['children'][0]]} / {names[m['children'][1]]}: kept {m['kept']:.3f}, "
                          f"exchanged {m['exchanged']:.3f}, best of two {m['best_of_two']:.3f}, exchange fits better "
                          f"in {m['views_exchange_fits_better']:.2f} of the views."]
        lines.append("")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
