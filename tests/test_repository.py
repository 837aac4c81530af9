"""The repository stays a code repository: ``results/`` within its size budget, no predictions committed."""

from pathlib import Path

import scapo

ROOT = Path(scapo.__file__).resolve().parent.parent
#: ``results/``'s budget in MB: generated tables, one status README and the cells archive of the tables whose
#: ``--finished-only`` rewrite is kept in the tree (per-sample floats as float32, ``scapo.bench.archive.PRECISION``;
#: figures as 256-colour PNGs, ``scapo.files.palette_png``); superseded tables and experiments leave the tree (the
#: history keeps them, ``docs/history.md``). Never raised.
RESULTS_BUDGET_MB = 15


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


def test_figures_are_written_as_palette_pngs_that_keep_their_colours_and_marks(tmp_path):
    """``atomic_savefig`` writes a PNG of at most 256 colours (``palette_png``): smaller than matplotlib's RGBA, the
    same size in pixels, its text fields (an output's mark) and resolution kept, and every pixel within a few levels
    of the original, the light axis panes of a 3-D plot included."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from PIL import Image

    from scapo.files import atomic_savefig, output_mark, palette_png

    rng = np.random.default_rng(0)
    fig = plt.figure(figsize=(4, 3))
    ax = fig.add_subplot(projection="3d")
    p = rng.normal(size=(500, 3))
    ax.scatter(*p.T, c=p[:, 0] > 0, cmap="coolwarm", s=2)
    ax.plot([0, 1], [0, 1], [0, 1], "k-")
    raw = io.BytesIO()
    fig.savefig(raw, format="png", dpi=90, metadata=output_mark("scapo preview"))
    png = atomic_savefig(fig, tmp_path / "f.png", dpi=90, metadata=output_mark("scapo preview"))
    plt.close(fig)
    assert png.stat().st_size < len(raw.getvalue())
    with Image.open(png) as im, Image.open(io.BytesIO(raw.getvalue())) as ref:
        assert im.mode == "P" and im.size == ref.size and im.text == ref.text
        assert round(im.info["dpi"][0]) == 90
        a = np.asarray(im.convert("RGB"), dtype=int)
        b = np.asarray(ref.convert("RGB"), dtype=int)
        assert np.percentile(np.abs(a - b).max(axis=2), 99) <= 16
        assert (np.abs(a - b).max(axis=2) <= 2).mean() > 0.95  # the white and grey areas exactly or nearly
    assert palette_png(png.read_bytes()) == png.read_bytes() or len(palette_png(png.read_bytes())) <= png.stat().st_size


def test_every_bench_script_parses_and_the_bench_readme_names_it():
    """``bench/``'s experiments are run again months later, from a new machine: each shell script parses
    (``bash -n``) and ``bench/README.md`` says what it makes."""
    import subprocess

    readme = (ROOT / "bench" / "README.md").read_text()
    for script in sorted((ROOT / "bench").glob("*.sh")):
        done = subprocess.run(["bash", "-n", str(script)], capture_output=True, text=True)
        assert done.returncode == 0, f"{script.name} does not parse: {done.stderr}"
        assert f"bench/{script.name}" in readme, f"bench/README.md does not name bench/{script.name}"
