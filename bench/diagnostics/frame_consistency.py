"""Object-frame consistency of predictions files already written (issue 52's target: at least 0.9).

For each file, on one split (val by default): the share of samples whose object-frame offset ``R_pred^T R_gt`` lies
within 15 deg of the offset most of them share (:func:`scapo.eval.frames.split_consistency`; 1 is one canonical
frame), strict and against the category's declared symmetric ground truth, as the ladder's cells report it; the
share of views whose base slot (``info["hinge_frames"]["base"]``, ``info["base_frame"]["slot"]`` or
``info["object_slot"]["slot"]`` (``base_slot`` alone), else slot 0) holds mostly points of the true base (the root
part, label 0), a ground-truth diagnosis of the base/child exchange; and the file's ``info["hinge_frames"]``
summary where it has one (the base slot, the view prior's use and swaps).

    python bench/diagnostics/frame_consistency.py --data DATA --pred LABEL=PREDICTIONS.npz [--pred ...] --out \\
        results/.../NAME

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each file's sha256).
"""

from __future__ import annotations

from pathlib import Path


def base_on_base(data: Path, preds, split: str) -> float:
    """Share of ``split``'s samples whose base slot (the ``hinge_frames``, ``base_frame`` or ``object_slot`` step's,
    else 0) gives more than half of its points to the true root part (label 0); NaN when the slot is empty in every
    sample."""
    import numpy as np

    from scapo.steps.hinge import prediction_arrays

    rows = np.flatnonzero(preds.split == split)
    gt = prediction_arrays(data, preds, ("part_label",))["part_label"][rows]
    info = preds.info
    base = (info.get("hinge_frames") or {}).get("base", (info.get("base_frame") or info.get("object_slot") or {})
                                                 .get("slot", 0))
    mine = preds.part_label[rows] == base
    n = mine.sum(1)
    share = (mine & (gt == 0)).sum(1) / np.maximum(n, 1)
    return float(np.mean(share[n > 0] > 0.5)) if (n > 0).any() else float("nan")


def main(argv=None) -> int:
    from scapo.bench.diagnosis import run_diagnosis
    from scapo.eval.frames import split_consistency

    def score(a, p) -> dict:
        strict, sym = split_consistency(Path(a.data), p, a.split)
        return {"strict": round(strict, 4), "sym": round(sym, 4), "samples": int((p.split == a.split).sum()),
                "base_slot_on_base": round(base_on_base(Path(a.data), p, a.split), 4),
                "hinge_frames": p.info.get("hinge_frames")}

    return run_diagnosis(argv, __doc__, "frame_consistency.py", score, render)


def render(a, rows: dict, card: dict) -> list[str]:
    """The Markdown lines of every file's frame consistency."""
    lines = [f"# Object-frame consistency ({Path(a.data).name}, {a.split})", "",
             "Share of samples within 15 deg of the one object-frame offset most of them share (1: one canonical "
             "frame); sym: against the declared symmetric ground truth as well. base slot on base: the share of "
             "views whose base slot holds mostly true base points (ground truth; the base/child exchange). "
             "hinge_frames: the step's base slot, whether its view prior was used (and the share of the file's "
             "views it exchanged).", "",
             "| predictions | samples | frame cons. | frame cons. sym | base slot on base | hinge_frames |",
             "|:--|--:|--:|--:|--:|:--|"]
    for label, r in rows.items():
        hf = r["hinge_frames"] or {}
        vp = hf.get("view_prior")
        note = "" if not hf else f"base {hf.get('base', 0)}" + (
            "" if vp is None else f", prior {'used' if vp['used'] else 'off'} "
                                  f"(swapped {vp.get('swapped_share', 0):.2f})")
        lines.append(f"| {label} | {r['samples']} | {r['strict']:.2f} | {r['sym']:.2f} | "
                     f"{r['base_slot_on_base']:.2f} | {note} |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
