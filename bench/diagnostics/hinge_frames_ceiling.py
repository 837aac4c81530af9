"""The ceiling of the ``hinge_frames`` step: a diagnosis with ground truth, not a method row (issue 52).

The step reads each part's rotation from its hinge (:mod:`scapo.steps.hinge`): the joint's axis and pivot and the
split of the points. This script gives it the **true** split, axes and pivots of every sample (train and the scored
split) and keeps the method's own part poses (they set only the per-part offsets, fitted on the training split), then
applies the step with the view prior. Scored by ``scapo evaluate``, the part rotation errors say what the step can
reach once a method's split and joints are right; the gap to the method's own ``+hinge-frames`` row is the split's.

    python bench/diagnostics/hinge_frames_ceiling.py --data DATA --pred PREDICTIONS.npz [...] --out-dir DIR

Writes ``DIR/<name>+true-joints+hinge-frames+view-prior.npz`` (label ``<method>-true-joints+hinge-frames+view-prior``;
``info["diagnosis"]`` says what came from the ground truth). The input files need their training-split predictions
(a self-supervised method's file has them).
"""

from __future__ import annotations

import sys
from pathlib import Path


def main(argv=None) -> int:
    """``bench/diagnostics/hinge_rows.py --frames --view-prior --true-joints`` with these arguments."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from hinge_rows import main as rows_main

    return rows_main(["--frames", "--view-prior", "--true-joints", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    raise SystemExit(main())
