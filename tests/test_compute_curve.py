"""``scapo bench compute``: accuracy against training compute (:mod:`scapo.bench.compute`)."""

import json

import pytest


def test_compute_curve_end_to_end(tmp_path, capsys):
    """Two budgets of the NPCS-style method at its test preset: each cell trains from scratch with the steps its
    budget buys (more for the larger one), the table and figure are written, and a rerun recomputes nothing;
    ``--data-only`` renders the data and measures the speed first."""
    from scapo.cli.main import main

    args = ["bench", "compute", "--category", "laptop", "--rungs", "one", "--methods", "npcs", "--budgets", "0.05,0.2",
            "--preset", "test", "--instances", "10", "--views", "1", "--train-views", "4", "--work", str(tmp_path / "w"),
            "--out", str(tmp_path / "o"), "--no-progress"]
    assert main([*args, "--data-only"]) == 0
    assert (tmp_path / "w" / "ladder" / "speed_npcs_test_cpu.json").is_file()  # measured alone, before any cell
    assert not (tmp_path / "w" / "ladder" / "compute").exists() and not (tmp_path / "o").exists()
    capsys.readouterr()
    assert main(args) == 0
    assert "measuring" not in capsys.readouterr().out
    name = "accuracy_vs_compute_laptop_one"
    table = json.loads((tmp_path / "o" / f"{name}.json").read_text())
    recs = sorted(table["records"], key=lambda x: x["budget_min"])
    assert [(x["method"], x["budget_min"]) for x in recs] == [("npcs", 0.05), ("npcs", 0.2)]
    assert recs[0]["wall"]["train_steps"] < recs[1]["wall"]["train_steps"]  # the budget buys steps
    assert recs[0]["budget_values"] != recs[1]["budget_values"]
    for x in recs:
        assert x["split"] == "val" and 0.0 <= x["frame_consistency_sym"] <= 1.0 and x["provenance"]["commit"]
    assert (tmp_path / "w" / "ladder" / "compute" / "b0.05" / "laptop" / "one" / "npcs_s0.json").is_file()
    assert (tmp_path / "o" / f"{name}.png").stat().st_size > 1000
    md = (tmp_path / "o" / f"{name}.md").read_text()
    assert "core-min" in md and "frame cons. sym" in md and "Provenance" in md
    assert main(args) == 0
    assert "measuring" not in capsys.readouterr().out
    assert json.loads((tmp_path / "o" / f"{name}.json").read_text())["records"] == table["records"]


@pytest.mark.parametrize("args,match", [
    (["--methods", "icp"], "not trained"),
    (["--budgets", "0"], "positive"),
    (["--budgets", "nan"], "positive"),
    (["--budgets", "1e9"], "at most 10080"),
    (["--budgets", "5,5"], "twice"),
    (["--methods", "npcs,npcs"], "twice"),
    (["--seeds", "0,0"], "twice"),
    (["--rungs", "one,paper"], "one rung"),
    (["--rungs", "bogus"], "unknown rung"),
    (["--methods", "nosuch"], "nosuch"),
])
def test_compute_curve_refuses_bad_arguments(tmp_path, capsys, args, match):
    from scapo.cli.main import main

    assert main(["bench", "compute", "--work", str(tmp_path / "w"), "--out", str(tmp_path / "o"), *args]) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not (tmp_path / "w").exists()  # refused before any work
