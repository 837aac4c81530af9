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
    """The paper-viewpoint Table 1 block: per method the mean over categories and seeds, the budget stated, the paper's
    rows as the mean of the same categories' columns."""
    import json

    from scapo.bench.headline import _table1_paper

    summary = {"S": 80.0, "D": 5.0, "R": 20.0, "R_median": 10.0, "R_sym_median": 8.0}
    rows = [{"method": "scapo", "category": c, "split": "test", "seed": s,
             "summary": {**summary, "S": 70.0 + 10 * s}, "info": {"alignment_inlier_ratio": [0.5, 0.7]}}
            for c in ("laptop", "eyeglasses") for s in (0, 1)]
    prov = {"training_seeds": {"scapo": [0, 1]}, "commits": ["abcdef0123"],
            "training_budget": {"core_minutes_per_run": 5.0}}
    (tmp_path / "table1_paper_two_categories.json").write_text(json.dumps({"results": rows, "provenance": prov}))
    text = "\n".join(_table1_paper(tmp_path))
    assert "5 core-minutes" in text and "abcdef0" in text
    assert "| SCAPO | 75.0 | 5.0 | 20.0 | 10.0 | 8.0 | 0.60 |" in text
    assert "| SCAPO, the paper | 80.8 | 2.3 | 3.6 | - | - | - |" in text  # (93.41 + 68.19) / 2, ...


def test_headline_refuses_a_results_folder_without_the_table_and_a_damaged_table(tmp_path, capsys):
    """A wrong --results or a damaged table JSON is a one-line error naming the file, and the README's block is left
    as it was (it was once rewritten from nothing and the command exited 0)."""
    from scapo.bench.headline import main

    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{START}\nthe numbers\n{END}\n")
    for check in ([], ["--check"]):
        assert main(["--readme", str(readme), "--results", str(tmp_path / "nosuch"), *check]) == 2
        assert "table1_paper_two_categories.json is not there" in capsys.readouterr().err
    (tmp_path / "table1_paper_two_categories.json").write_text('{"results": [')
    assert main(["--readme", str(readme), "--results", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "table1_paper_two_categories.json is not a table of scapo bench" in err and err.count("\n") == 1
    assert "the numbers" in readme.read_text()


def test_the_option_reference_of_the_usage_page_is_generated_from_the_configs():
    """docs/usage.md's option reference is what ``python -m scapo.cli.options_reference`` writes from the dataclasses'
    field docs: every prediction step and every preset field, with its type and default; a stale block is found."""
    import dataclasses

    from scapo.cli.options_reference import field_docs, options_reference, update_usage
    from scapo.steps import StepOptions

    usage = ROOT / "docs" / "usage.md"
    assert update_usage(usage, check=True), "docs/usage.md's option reference is stale: python -m scapo.cli.options_reference"
    text = options_reference()
    for f in dataclasses.fields(StepOptions):
        assert f"| `{f.name}` |" in text and field_docs(StepOptions)[f.name]
    assert "| `losses." in text and "| `refine.stage2_starts` | str | `'off'` |" in text  # SCAPO's groups, dotted
    assert "| `stage0_epochs` |" in text and "| `drct_noise` |" in text  # the baselines' presets
