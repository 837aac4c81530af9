"""How far a dataset regenerated on another CPU kind is from the one the archived cells were computed on, measured
through the archived predictions: every archived cell of a dataset folder is scored again, under its record's
protocol, against this machine's regeneration of that dataset, and its per-sample metrics are compared with the
archived ones (issue 31: the premise of :func:`scapo.bench.archive.reconcile_dataset`, that datasets differ across
CPU kinds only in the last bits of double-precision ground truth).

The scores depend on the ground truth (part labels of every point, part poses, joint axes, pivots, states, camera
pose) and, for the methods scored in their own canonical frame, on the training split's ground truth too, so equal
per-sample segmentation (S, exactly) and errors equal to rounding say that this machine's labels and ground truth
are the archived dataset's; the archived predictions themselves are not recomputed (the hash check is skipped).

    python bench/cross_cpu_check.py --archive results/tables_cells/table1_table3 \
        --work ../wt31/bench_work/table1_cpu --out results/diagnostics/cross_cpu/table1
"""

from __future__ import annotations

import argparse
import json
import lzma
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scapo.errors import ScapoError  # noqa: E402
from scapo.eval import evaluate  # noqa: E402
from scapo.files import atomic_write_text, check_output_dir  # noqa: E402
from scapo.provenance import provenance  # noqa: E402


def check_folder(archived: Path, data: Path) -> list[dict]:
    """One row per archived cell of ``archived`` (``<archive>/<dataset folder>``) scored on ``data``."""
    from scapo.data import load

    here = load(data, "test").dataset_hash
    rows = []
    for rec_path in sorted((archived / "cells").glob("*.json")):
        rec = json.loads(rec_path.read_text())
        key, _, protocol = rec_path.name[:-len(".json")].rpartition(".")
        xz = archived / f"predictions_{key}.npz.xz"
        if not xz.is_file():
            continue
        with tempfile.TemporaryDirectory() as tmp:
            pred = Path(tmp) / "p.npz"
            pred.write_bytes(lzma.decompress(xz.read_bytes()))
            res = evaluate(data, pred, protocol=protocol, check_hash=False)
        old = pd.read_parquet(archived / "cells" / f"{key}.{protocol}.parquet")
        new = res.per_sample.reset_index(drop=True)
        cols = [c for c in old.columns if c in new.columns and pd.api.types.is_numeric_dtype(old[c])]
        a, b = old[cols].to_numpy(dtype=np.float64), new[cols].to_numpy(dtype=np.float64)
        same_nan = bool((np.isnan(a) == np.isnan(b)).all())
        diff = np.where(np.isnan(a) & np.isnan(b), 0.0, np.abs(a - b))
        worst = int(np.nanargmax(diff.max(axis=0))) if diff.size else 0
        rows.append({"folder": archived.name, "cell": key, "protocol": protocol,
                     "archived_dataset": str(rec.get("dataset_hash"))[:12], "this_dataset": here[:12],
                     "samples": len(new), "S_identical": bool(np.array_equal(old["S"].to_numpy(), new["S"].to_numpy())),
                     "nan_pattern_same": same_nan, "max_abs_diff": float(np.nanmax(diff)) if diff.size else 0.0,
                     "worst_column": cols[worst] if cols else "",
                     "summary_S": (rec["summary"]["S"], res.summary["S"]),
                     "summary_R": (rec["summary"]["R"], res.summary["R"])})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--archive", type=Path, required=True, help="a cells archive (results/tables_cells/...)")
    ap.add_argument("--work", type=Path, required=True, help="the bench work folder holding this machine's datasets")
    ap.add_argument("--out", type=Path, required=True, help="output path without suffix (.md and .json written)")
    a = ap.parse_args(argv)
    try:
        check_output_dir(a.out.parent, "output folder")
        rows = []
        for archived in sorted(p for p in a.archive.iterdir() if (p / "cells").is_dir()):
            data = a.work / archived.name
            if not (data / "card.json").is_file():
                print(f"{archived.name}: no dataset in {a.work}; skipped", file=sys.stderr)
                continue
            rows += check_folder(archived, data)
            print(f"{archived.name}: {sum(r['folder'] == archived.name for r in rows)} cells scored", flush=True)
    except (ScapoError, OSError, ValueError, KeyError) as e:
        print(f"scapo: bench/cross_cpu_check.py: {e}", file=sys.stderr)
        return 2
    if not rows:
        print("scapo: bench/cross_cpu_check.py: no archived cell with predictions and a dataset here", file=sys.stderr)
        return 2
    prov = provenance(archive=str(a.archive), work=str(a.work))
    lines = [f"# Archived cells scored on this machine's regenerated datasets ({prov['device']})", "",
             f"commit {prov['commit']}; {len(rows)} cells; S identical in {sum(r['S_identical'] for r in rows)}; "
             f"largest per-sample difference {max(r['max_abs_diff'] for r in rows):.3g}", "",
             "| folder | cell | protocol | archived dataset | this dataset | samples | S identical | NaNs same | "
             "max abs diff | in column | S (archived / here) | R (archived / here) |",
             "|---|---|---|---|---|--:|---|---|--:|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['folder']} | {r['cell']} | {r['protocol']} | {r['archived_dataset']} | "
                     f"{r['this_dataset']} | {r['samples']} | {r['S_identical']} | {r['nan_pattern_same']} | "
                     f"{r['max_abs_diff']:.3g} | {r['worst_column']} | {r['summary_S'][0]:.6f} / "
                     f"{r['summary_S'][1]:.6f} | {r['summary_R'][0]:.6f} / {r['summary_R'][1]:.6f} |")
    atomic_write_text(a.out.with_suffix(".md"), "\n".join(lines) + "\n")
    atomic_write_text(a.out.with_suffix(".json"), json.dumps({"provenance": prov, "rows": rows}, indent=1,
                                                             default=str) + "\n")
    print("\n".join(lines[:3]))
    print(f"wrote {a.out.with_suffix('.md')} and .json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
