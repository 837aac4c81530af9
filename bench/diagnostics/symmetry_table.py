"""Table of the symmetry measurements (``scapo assets symmetry --json``) of several asset versions side by side:

    python bench/diagnostics/symmetry_table.py --column v1=results/symmetry/before --column v2=results/symmetry/v2 \\
        --column v3=results/symmetry/after --out results/symmetry/README.md

Each ``--column LABEL=FOLDER`` holds one JSON per category (a category missing from a folder gets a dash). The
declared symmetries, whether they hold and the share of views a declared one explains are the last column's. The
table replaces the block between ``<!-- table: bench/diagnostics/symmetry_table.py -->`` and ``<!-- end table -->``
of ``--out``
(appended when the file has none)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

CATEGORIES = ["laptop", "suitcase", "scissors", "basket", "safe", "oven", "drawer", "eyeglasses", "washer"]


def _read(folder: Path, category: str) -> dict | None:
    if not (folder / f"{category}.json").is_file():
        return None
    return json.loads((folder / f"{category}.json").read_text())


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _views(r: dict | None) -> str:
    if r is None:
        return "-"
    return f"{_pct(r.get('ambiguous_one_sided'))} / {_pct(r.get('ambiguous_two_sided'))}"


def _maps(r: dict | None) -> str:
    if r is None:
        return "-"
    return f"{sum(1 for s in r['self_maps'] if s['maps'])}/{len(r['self_maps'])}"


def _declared(a: dict | None) -> tuple[str, str, str]:
    if a is None:
        return "-", "-", "-"
    decl = ", ".join(f"{'exact' if d.get('slack', 0.004) <= 0.004 else 'approximate'} (parts {d['parts']})"
                     for d in a["declared"]) or "none"
    if not a["declared"]:
        return decl, "-", "-"
    return decl, "yes" if a["declared_hold"] else "NO", _pct(a.get("ambiguous_declared"))


def _column(text: str) -> tuple[str, Path]:
    label, eq, folder = text.partition("=")
    if not eq or not label or not folder:
        raise argparse.ArgumentTypeError(f"--column wants LABEL=FOLDER, got {text!r}")
    return label, Path(folder)


def table(columns: list[tuple[str, Path]]) -> str:
    """The markdown table and its provenance lines for ``columns`` [(label, folder)], in that order."""
    labels = [c[0] for c in columns]
    head = (["category"] + [f"ambiguous views {lb} (one-sided / two-sided)" for lb in labels]
            + [f"undeclared mesh self-maps {lb} (instance states)" for lb in labels]
            + [f"declared symmetries ({labels[-1]})", "hold on the meshes", "views a declared one explains"])
    lines = ["| " + " | ".join(head) + " |", "|---|" + "--:|" * (2 * len(labels)) + "---|---|--:|"]
    prov: dict[str, tuple[set, list]] = {lb: (set(), []) for lb in labels}
    for c in CATEGORIES:
        reps = [_read(folder, c) for _, folder in columns]
        cells = [c] + [_views(r) for r in reps] + [_maps(r) for r in reps] + list(_declared(reps[-1]))
        lines.append("| " + " | ".join(cells) + " |")
        for lb, r in zip(labels, reps):
            if r is not None:
                prov[lb][0].add(str(r.get("provenance", {}).get("commit", "?")))
                prov[lb][1].append(float(r.get("seconds", 0.0)))
    lines.append("")
    for (lb, folder), (commits, seconds) in zip(columns, prov.values()):
        if commits:
            lines.append(f"- {lb} (`{folder}`): commit(s) {', '.join(sorted(commits))}; {sum(seconds) / 60:.0f} min "
                         "of one core in all")
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--column", type=_column, action="append", required=True, metavar="LABEL=FOLDER")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    text = table(args.column)
    out = args.out
    if out.is_file():
        old = out.read_text()
        start, end = "<!-- table: bench/diagnostics/symmetry_table.py -->\n", "<!-- end table -->\n"
        if start in old and end in old:
            text = old.split(start)[0] + start + text + end + old.split(end, 1)[1]
        else:
            text = old + "\n" + start + text + end
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
