"""Slot identity of SCAPO's stage-2 pseudo-labels and of its network, on the training split (a ground-truth diagnosis
of issue 52's laptop frame).

For each predictions file of a SCAPO run trained with ``split_labels`` (its ``info["run"]`` holds
``split_labels.npy``, the pseudo-labels of every training cloud), per training view: the permutation of slots that
best matches the true parts, (a) for the pseudo-labels and (b) for the network's one-pass labels of the same view
(the file's training split). A split can be right within every view (high per-view accuracy) while the slots
exchange parts across views (the best single permutation scores less, and one permutation holds in only part of the
views); this shows whether the pseudo-labels do that and whether the network follows them.

    python bench/diagnostics/slot_identity.py --data DATA --pred LABEL=PREDICTIONS.npz [--pred ...] --out \\
        results/.../NAME

Columns: per-view best accuracy; accuracy of the slots as they are (identity permutation); of the best single
permutation over all views; the share of views whose best permutation is each permutation; the share of views where
the network's best permutation is the pseudo-labels'. Writes ``<out>.{md,json}`` with provenance.
"""

from __future__ import annotations

import itertools
from pathlib import Path


def slot_identity(data: Path, preds) -> dict:
    """The columns above for one predictions file (its run's ``split_labels.npy``; the dataset's training split).

    Raises:
        PredictionError: no ``info["run"]``, a run without ``split_labels.npy``, or labels of another size."""
    import numpy as np

    from scapo.data import load
    from scapo.errors import PredictionError

    run = preds.info.get("run")
    if not run or not (Path(run) / "split_labels.npy").is_file():
        raise PredictionError(f"predictions of {preds.method!r} name no run with split_labels.npy (info['run'] "
                              f"{run!r}): slot identity reads a SCAPO run trained with split_labels")
    tr = load(data, "train")
    gt = tr.arrays(["part_label"])["part_label"]
    pseudo = np.load(Path(run) / "split_labels.npy", allow_pickle=False)
    if pseudo.shape != gt.shape:
        raise PredictionError(f"{run}/split_labels.npy has shape {pseudo.shape}, the training split {gt.shape}")
    rows = {(int(i), int(v)): k for k, (i, v, s) in enumerate(zip(preds.instance_id, preds.view_id, preds.split))
            if s == "train"}
    keys = list(tr.keys())
    missing = [k for k in keys if k not in rows]
    if missing:
        raise PredictionError(f"predictions of {preds.method!r} lack {len(missing)} training views (e.g. {missing[0]})")
    net = preds.part_label[[rows[k] for k in keys]]
    P = int(gt.max()) + 1
    perms = list(itertools.permutations(range(P)))
    ident = perms.index(tuple(range(P)))

    def best(lbl):
        acc = np.stack([(np.asarray(q)[np.clip(lbl, 0, P - 1)] == gt).mean(1) for q in perms], 1)
        return acc.argmax(1), acc

    bp, ap = best(pseudo)
    bn, an = best(net)
    r = 4
    return {"views": int(len(gt)), "perms": [list(q) for q in perms],
            "pseudo_per_view_best": round(float(ap.max(1).mean()), r),
            "pseudo_as_is": round(float(ap[:, ident].mean()), r),
            "pseudo_best_single_perm": round(float(ap.mean(0).max()), r),
            "pseudo_perm_shares": [round(float(x), r) for x in np.bincount(bp, minlength=len(perms)) / len(bp)],
            "net_per_view_best": round(float(an.max(1).mean()), r),
            "net_as_is": round(float(an[:, ident].mean()), r),
            "net_best_single_perm": round(float(an.mean(0).max()), r),
            "net_perm_shares": [round(float(x), r) for x in np.bincount(bn, minlength=len(perms)) / len(bn)],
            "net_follows_pseudo": round(float((bp == bn).mean()), r), "run": str(run)}


def main(argv=None) -> int:
    from scapo.bench.diagnosis import run_diagnosis

    return run_diagnosis(argv, __doc__, "slot_identity.py", lambda a, p: slot_identity(Path(a.data), p), render)


def render(a, rows: dict, card: dict) -> list[str]:
    """The Markdown lines: one row per file."""
    lines = [f"# Slot identity of the pseudo-labels and the network ({Path(a.data).name}, train)", "",
             "Per training view, the slot permutation that best matches the true parts. per-view: mean of each view's "
             "best accuracy; as is: the slots unpermuted; one perm: the best single permutation over all views; "
             "perm shares: the share of views whose best permutation is each (in the order of `perms` in the JSON); "
             "network follows: views where the network's best permutation is the pseudo-labels'.", "",
             "| file | views | pseudo per-view | pseudo as is | pseudo one perm | pseudo perm shares "
             "| network per-view | network one perm | network perm shares | network follows |",
             "|:--|--:|--:|--:|--:|:--|--:|--:|:--|--:|"]
    for label, r in rows.items():
        lines.append(f"| {label} | {r['views']} | {r['pseudo_per_view_best']:.3f} | {r['pseudo_as_is']:.3f} | "
                     f"{r['pseudo_best_single_perm']:.3f} | {' / '.join(f'{x:.2f}' for x in r['pseudo_perm_shares'])} "
                     f"| {r['net_per_view_best']:.3f} | {r['net_best_single_perm']:.3f} | "
                     f"{' / '.join(f'{x:.2f}' for x in r['net_perm_shares'])} | {r['net_follows_pseudo']:.3f} |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
