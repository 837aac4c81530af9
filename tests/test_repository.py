"""The repository stays a code repository: ``results/`` within its size budget, no predictions committed."""

from pathlib import Path

import scapo

ROOT = Path(scapo.__file__).resolve().parent.parent
#: ``results/``'s budget in MB: 67.3 MB once the cells archive kept each dataset folder's per-sample metrics in one
#: packed file (``scapo.bench.archive.PACKED``) instead of 588 small parquet files (81.5 MB before). It is lowered as
#: superseded tables leave, never raised.
RESULTS_BUDGET_MB = 70


def test_results_fit_their_size_budget():
    files = [p for p in (ROOT / "results").rglob("*") if p.is_file()]
    total = sum(p.stat().st_size for p in files) / 2 ** 20
    largest = sorted(files, key=lambda p: -p.stat().st_size)[:5]
    assert total <= RESULTS_BUDGET_MB, (
        f"results/ is {total:.1f} MB, over its {RESULTS_BUDGET_MB} MB budget; largest: "
        + ", ".join(f"{p.relative_to(ROOT)} ({p.stat().st_size / 2 ** 20:.1f} MB)" for p in largest)
        + ". Keep predictions and checkpoints out of results/ (a cells archive keeps records, per-sample metrics and "
          "the predictions' sha256), and let superseded tables and figures leave the tree")


def test_no_predictions_or_checkpoints_are_committed_in_results():
    heavy = [p.relative_to(ROOT) for p in (ROOT / "results").rglob("*")
             if p.is_file() and (p.name.startswith("predictions_") or p.suffix == ".pt")]
    assert not heavy, f"predictions or checkpoints in results/: {heavy[:5]}"


def test_no_scripts_are_kept_in_results():
    """``results/`` holds generated tables, their cells and READMEs; the experiments that make them live in
    ``bench/`` (the reusable ones) and one-off scripts leave the tree (``docs/history.md`` names the commit that had
    them)."""
    scripts = [str(p.relative_to(ROOT)) for p in (ROOT / "results").rglob("*")
               if p.is_file() and p.suffix in (".py", ".sh", ".ipynb")]
    assert not scripts, f"scripts in results/: {scripts[:5]}; move a reusable one to bench/, delete a one-off one"


def test_the_readme_is_read_in_two_minutes():
    """README.md: what scapo is, the two commands, the headline table, the status, the commands, links; at most 8 KB
    (the reference is docs/usage.md, the developers' page docs/DEVELOPING.md)."""
    size = (ROOT / "README.md").stat().st_size
    assert size <= 8 * 1024, f"README.md is {size} bytes, over 8 KB: move detail to docs/"
    size = (ROOT / "results" / "README.md").stat().st_size
    assert size <= 10 * 1024, (f"results/README.md is {size} bytes, over 10 KB: one status paragraph per table, the "
                               "narrative in docs/results_notes.md")


def test_the_package_loads_no_script_and_cites_no_work_log():
    """The library never loads a file of ``bench/`` (no module loading by path, no ``bench`` path joined), and its
    docstrings say what and why, not in which session or issue it was measured."""
    import re

    loads, cites = [], []
    for p in (ROOT / "scapo").rglob("*.py"):
        text = p.read_text()
        if re.search(r"spec_from_file_location|runpy|exec_module|[\"']bench[\"']\s*/|/\s*[\"']bench[\"']", text):
            loads.append(str(p.relative_to(ROOT)))
        cites += [f"{p.relative_to(ROOT)}:{i}" for i, line in enumerate(text.splitlines(), 1)
                  if re.search(r"\b(session|issue) [0-9]", line)]
    assert not loads, f"modules of scapo/ that load files by path: {loads}"
    assert not cites, f"work-log citations in scapo/: {cites[:5]}"
