"""How far a dataset regenerated on another CPU kind is from the one the archived cells were computed on, measured
through the archived predictions: every archived cell of a dataset folder is scored again, under its record's
protocol, against this machine's regeneration of that dataset, and its per-sample metrics are compared with the
archived ones (issue 31: the premise of :func:`scapo.bench.archive.reconcile_dataset`, that datasets differ across
CPU kinds only in the last bits of double-precision ground truth).

The scores depend on the ground truth (part labels of every point, part poses, joint axes, pivots, states, camera
pose) and, for the methods scored in their own canonical frame, on the training split's ground truth too, so equal
per-sample segmentation (S, exactly) and errors equal to rounding say that this machine's labels and ground truth
are the archived dataset's; the archived predictions themselves are not recomputed (the hash check is skipped).

    python bench/diagnostics/cross_cpu_check.py --archive results/tables_cells/table1_table3 \
        --work ../wt31/bench_work/table1_cpu --out results/diagnostics/cross_cpu/table1

With ``--adopt``, each folder whose cells name a dataset that is not pinned is then adopted
(:func:`scapo.bench.archive.adopt_dataset`: its ICP cell computed again on this machine's inputs, its cells
re-labelled with this machine's dataset, which is pinned); the report lists each folder's outcome.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from scapo.errors import ScapoError  # noqa: E402
from scapo.files import atomic_write_text, check_output_dir  # noqa: E402
from scapo.provenance import provenance  # noqa: E402


def check_folder(archived: Path, data: Path) -> list[dict]:
    """One row per archived cell of ``archived`` (``<archive>/<dataset folder>``) scored on ``data``
    (:func:`scapo.bench.archive.rescore_cell`)."""
    from scapo.bench.archive import rescore_cell
    from scapo.data import load

    here = load(data, "test").dataset_hash
    rows = []
    for rec_path in sorted((archived / "cells").glob("*.json")):
        row = rescore_cell(archived, rec_path, data)
        if row is None:
            continue
        rows.append({"folder": archived.name, **{k: v for k, v in row.items() if k not in ("result", "predictions")},
                     "archived_dataset": row["archived_dataset"][:12], "this_dataset": here[:12]})
    return rows


def _adoption_line(name: str, r: dict) -> str:
    """One folder's adoption report as a row of the markdown table."""
    icp = "; ".join(f"{u['max_abs_diff']:.3g} ({u['field'] or '-'})" for u in r.get("untrained", []))
    diff = f"{r['max_abs_diff']:.3g}" if "max_abs_diff" in r else ""
    return (f"| {name} | {r['status']} | {str(r.get('from', ''))[:12]} | {str(r.get('dataset_hash', ''))[:12]} | "
            f"{r.get('cells', '')} | {diff} | {icp} | {r.get('why', '')} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--archive", type=Path, required=True, help="a cells archive (results/tables_cells/...)")
    ap.add_argument("--work", type=Path, required=True, help="the bench work folder holding this machine's datasets")
    ap.add_argument("--out", type=Path, required=True, help="output path without suffix (.md and .json written)")
    ap.add_argument("--adopt", action="store_true", help="then adopt every folder whose cells name an unpinned "
                    "dataset (scapo.bench.archive.adopt_dataset)")
    a = ap.parse_args(argv)
    adopted: dict[str, dict] = {}
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
            if a.adopt:
                from scapo.bench.archive import adopt_dataset

                rep = adopt_dataset(data, a.archive, progress=False)
                adopted[archived.name] = {k: v for k, v in rep.items() if k != "cell_evidence"}
                print(f"{archived.name}: adoption {rep['status']} {rep.get('why', '')}", flush=True)
    except (ScapoError, OSError, ValueError, KeyError) as e:
        print(f"scapo: bench/diagnostics/cross_cpu_check.py: {e}", file=sys.stderr)
        return 2
    if not rows:
        print("scapo: bench/diagnostics/cross_cpu_check.py: no archived cell with predictions and a dataset here",
              file=sys.stderr)
        return 2
    prov = provenance(archive=str(a.archive), work=str(a.work))
    lines = [f"# Archived cells scored on this machine's regenerated datasets ({prov['device']})", "",
             f"commit {prov['commit']}; {len(rows)} cells; S identical in {sum(r['S_identical'] for r in rows)}; "
             f"largest per-sample difference {max(r['max_abs_diff'] for r in rows):.3g}", "",
             "| folder | cell | protocol | archived dataset | this dataset | samples | S identical | NaNs same | "
             "max abs diff | in column | S (archived / here) | R (archived / here) |",
             "|---|---|---|---|---|--:|---|---|--:|---|---|---|"]
    if adopted:
        lines[4:4] = ["## Adoption (scapo.bench.archive.adopt_dataset)", "",
                      "| folder | outcome | from | to | cells | largest score difference | ICP computed again: "
                      "largest difference (field) | why not |", "|---|---|---|---|--:|--:|---|---|",
                      *(_adoption_line(name, r) for name, r in adopted.items()), "", "## Scores", ""]
    atomic_write_text(a.out.with_suffix(".md"), "\n".join(lines) + "\n")
    atomic_write_text(a.out.with_suffix(".json"), json.dumps({"provenance": prov, "rows": rows, "adopted": adopted},
                                                            indent=1, default=str) + "\n")
    print("\n".join(lines[:3]))
    print(f"wrote {a.out.with_suffix('.md')} and .json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
