"""The README's generated block of headline numbers is current (``python -m scapo.bench.headline``)."""

from pathlib import Path

import pytest

import scapo
from scapo.bench.headline import END, START, headline, update_readme

ROOT = Path(scapo.__file__).resolve().parent.parent


def test_readme_headline_block_is_generated_from_results():
    assert update_readme(ROOT / "README.md", ROOT / "results", check=True), (
        "README.md's headline block differs from results/: run python -m scapo.bench.headline")


def test_headline_block_is_rewritten_and_refused_without_markers(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{START}\nold numbers\n{END}\n\ntail\n")
    assert not update_readme(readme, ROOT / "results", check=True)
    assert "old numbers" in readme.read_text()  # --check writes nothing
    assert not update_readme(readme, ROOT / "results")
    text = readme.read_text()
    assert "old numbers" not in text and headline(ROOT / "results") in text and text.endswith("tail\n")
    assert update_readme(readme, ROOT / "results", check=True)
    readme.write_text("# no block\n")
    with pytest.raises(ValueError, match="no headline block"):
        update_readme(readme, ROOT / "results")


def test_headline_of_table1_paper_two_categories(tmp_path):
    """The paper-viewpoint Table 1 block: per method the mean over categories and seeds, the budget stated."""
    import json

    from scapo.bench.headline import _table1_paper

    assert _table1_paper(tmp_path) == []
    summary = {"S": 80.0, "D": 5.0, "R_median": 10.0, "R_sym_median": 8.0}
    rows = [{"method": "scapo", "category": c, "split": "test", "seed": s,
             "summary": {**summary, "S": 70.0 + 10 * s}, "info": {"alignment_inlier_ratio": [0.5, 0.7]}}
            for c in ("laptop", "eyeglasses") for s in (0, 1)]
    prov = {"training_seeds": {"scapo": [0, 1]}, "commits": ["abcdef0123"],
            "training_budget": {"core_minutes_per_run": 5.0}}
    (tmp_path / "table1_paper_two_categories.json").write_text(json.dumps({"results": rows, "provenance": prov}))
    text = "\n".join(_table1_paper(tmp_path))
    assert "5 core-minutes" in text and "abcdef0" in text
    assert "| SCAPO | 75.0 | 5.0 | 10.0 | 8.0 | 0.60 |" in text


def test_headline_of_the_laptop_with_the_hinge_steps(tmp_path):
    """The hinge block: one-pass and with the steps per method and budget, means over seeds, the frame consistency of
    the consistency file's rows of that label; absent without both files."""
    import json

    from scapo.bench.headline import STEPS, _hinge

    assert _hinge(tmp_path) == []
    folder = tmp_path / "table1_paper_hinge_45min"
    folder.mkdir()
    rows = [{"method": m, "category": "laptop", "split": "test", "seed": s,
             "summary": {"S": 70.0 + 10 * s + (10 if m != "scapo" else 0), "D_median": 1.0, "R_median": 2.0}}
            for m in ("scapo", "scapo" + STEPS) for s in (0, 1)]
    (folder / "laptop_scapo.json").write_text(json.dumps({"results": rows}))
    assert _hinge(tmp_path) == []  # no consistency file yet
    cons = {f"{m}-s{s}": {"strict": 0.5 + 0.4 * (m != "scapo") + 0.02 * s} for m in ("scapo", "scapo" + STEPS)
            for s in (0, 1)}
    (folder / "laptop_scapo_consistency.json").write_text(json.dumps({"rows": cons}))
    text = "\n".join(_hinge(tmp_path))
    assert "| SCAPO | 45 | 75.0 | 1.00 | 2.00 | 0.51 |" in text
    assert "| SCAPO + hinge steps | 45 | 85.0 | 1.00 | 2.00 | 0.91 |" in text
