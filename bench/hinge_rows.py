"""The hinge step (:mod:`scapo.methods.hinge`) applied to predictions files already written, e.g. a table's cells.

    python bench/hinge_rows.py --data DATA --pred PREDICTIONS.npz [...] --out-dir DIR

Writes ``DIR/<name>+hinge.npz`` for each input (the label ``<method>+hinge``; the source's label in
``info["hinge_source"]``), to be scored beside the sources by ``scapo evaluate --pred SOURCES... HINGED...``. The
step reads only each prediction and the points, so this is what ``scapo predict --option hinge=true`` gives, without
predicting again: the one-pass predictions keep the commit that made them, and the step's own commit is this one's.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    from scapo.errors import ScapoError
    from scapo.methods.hinge import hinge_predictions

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--pred", nargs="+", required=True)
    ap.add_argument("--out-dir", required=True)
    ap.add_argument("--axis", action="store_true", help="also the axes from the parts' planes (hinge_axis=true)")
    a = ap.parse_args(argv)
    out = Path(a.out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for f in a.pred:
            dst = out / (Path(f).stem + ("+hinge-axis.npz" if a.axis else "+hinge.npz"))
            hinge_predictions(a.data, f, axis_from_planes=a.axis).save(dst)
            print(f"wrote {dst}")
    except (ScapoError, OSError) as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
