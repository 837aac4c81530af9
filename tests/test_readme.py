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
