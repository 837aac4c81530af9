"""Table of the symmetry measurements (``scapo assets symmetry --json``), before and after the asymmetric parts of
issue 29: python bench/symmetry_table.py --before results/symmetry/before --after results/symmetry/after
--out results/symmetry/README.md (a category missing from a folder gets a dash)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

CATEGORIES = ["laptop", "suitcase", "scissors", "basket", "safe", "oven", "drawer", "eyeglasses", "washer"]


def _read(folder: Path | None, category: str) -> dict | None:
    if folder is None or not (folder / f"{category}.json").is_file():
        return None
    return json.loads((folder / f"{category}.json").read_text())


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _row(category: str, b: dict | None, a: dict | None) -> str:
    def get(r, k):
        return None if r is None else r.get(k)

    def maps(r):
        if r is None:
            return "-"
        return f"{sum(1 for s in r['self_maps'] if s['maps'])}/{len(r['self_maps'])}"

    decl = "-" if a is None else (", ".join(
        f"{'exact' if d.get('slack', 0.004) <= 0.004 else 'approximate'} ({'parts ' + str(d['parts'])})"
        for d in a["declared"]) or "none")
    hold = "-" if a is None or not a["declared"] else ("yes" if a["declared_hold"] else "NO")
    return (f"| {category} | {_pct(get(b, 'ambiguous_one_sided'))} / {_pct(get(b, 'ambiguous_two_sided'))} | "
            f"{_pct(get(a, 'ambiguous_one_sided'))} / {_pct(get(a, 'ambiguous_two_sided'))} | {maps(b)} | {maps(a)} | "
            f"{decl} | {hold} | {_pct(get(a, 'ambiguous_declared')) if a and a['declared'] else '-'} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--before", type=Path, default=None)
    p.add_argument("--after", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    lines = [
        "| category | ambiguous views before (one-sided / two-sided) | after | undeclared mesh self-maps before "
        "(instance states) | after | declared symmetries (after) | hold on the meshes | views a declared one "
        "explains |",
        "|---|--:|--:|--:|--:|---|---|--:|",
    ]
    prov = {}
    for c in CATEGORIES:
        b, a = _read(args.before, c), _read(args.after, c)
        lines.append(_row(c, b, a))
        for tag, r in (("before", b), ("after", a)):
            if r is not None:
                pv = r.get("provenance", {})
                prov.setdefault(tag, set()).add(f"{pv.get('commit', '?')}")
                prov.setdefault(tag + "_seconds", []).append(r.get("seconds", 0.0))
    lines.append("")
    for tag in ("before", "after"):
        if tag in prov:
            minutes = sum(prov[tag + "_seconds"]) / 60
            lines.append(f"- {tag}: commit(s) {', '.join(sorted(prov[tag]))}; {minutes:.0f} min "
                         "of one core in all")
    text = "\n".join(lines) + "\n"
    out = args.out
    if out.is_file():
        old = out.read_text()
        start, end = "<!-- table: bench/symmetry_table.py -->\n", "<!-- end table -->\n"
        if start in old and end in old:
            text = old.split(start)[0] + start + text + end + old.split(end, 1)[1]
        else:
            text = old + "\n" + start + text + end
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
