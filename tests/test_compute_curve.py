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
            "--out", str(tmp_path / "o"), "--no-progress", "--workers", "1"]  # rendered in this process
    assert main([*args, "--data-only"]) == 0
    speeds = list((tmp_path / "w" / "ladder").glob("speed_npcs_test_cpu_laptop_one_*.json"))  # named by its data
    assert len(speeds) == 1  # measured alone, before any cell
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
    narrower = [a if a != "0.05,0.2" else "0.05" for a in args]  # a rerun with fewer budgets into the same --out
    assert main(narrower) == 2
    assert "row(s) this run does not make" in capsys.readouterr().err
    assert json.loads((tmp_path / "o" / f"{name}.json").read_text())["records"] == table["records"]  # kept


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
    (["--from-table", "--rungs", "one"], "single views"),
])
def test_compute_curve_refuses_bad_arguments(tmp_path, capsys, args, match):
    from scapo.cli.main import main

    assert main(["bench", "compute", "--work", str(tmp_path / "w"), "--out", str(tmp_path / "o"), *args]) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not (tmp_path / "w").exists()  # refused before any work


def test_from_table_uses_the_tables_presets_speeds_and_finished_runs(tmp_path, capsys, monkeypatch):
    """``--from-table``: the table's preset (one for every category) and charged one-time work (hand-built speeds:
    16 clouds/s at batch 16, 10 steps an epoch; SCAPO's 10 + 10 epochs take 200 s, so one core-minute less its 20 s
    of pseudo-labelling buys 2 + 2; NPCS's 10 take 100 s: 6); the table's finished
    run of the same preset and seed is copied to the cell's run (an unfinished one, or one of another schedule, is
    not); a work folder without the table's dataset is refused with the command that renders it."""
    from scapo.bench.cells import Cell
    from scapo.bench.compute import _reuse_table_run, _table_dataset, _table_presets
    from scapo.bench.experiments import dataset_dir
    from scapo.bench.ladder import cells_dir, rung_config
    from scapo.errors import ConfigError
    from scapo.provenance import cpu_kind

    kw = {"viewpoints": "paper", "train_views": 4}
    data = dataset_dir(tmp_path, "laptop", 10, 2, 0, kw)
    monkeypatch.setattr("scapo.data.load", lambda d, split: [None] * 160)  # its 160 training clouds, not rendered
    base = {"batch_size": 16, "train_clouds": 160, "max_steps_per_epoch": 0, "stage1_epoch_s": 0.0,
            "stage1_clouds_per_s": 16.0, "unit": "core-seconds", "cpu_kind": cpu_kind(), "data": str(data)}
    speeds = {"scapo_cpu": {**base, "method": "scapo", "stage1_epochs": 10, "stage2_epochs": 10,
                                   "stage2_clouds_per_s": 16.0, "stage2_epoch_s": 0.0, "fixed_s": 20.0},
              "npcs_cpu": {**base, "method": "npcs", "stage1_epochs": 10, "iterations": 0, "fixed_s": 0.0}}
    for key, row in speeds.items():
        path = tmp_path / "speeds" / f"{data.name}_{key}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps([row]))
    presets = _table_presets(["scapo", "npcs"], "laptop", 1.0, "cpu", tmp_path, 10, 2, 4, 0, "paper")
    assert {m: v[1]["preset"] for m, v in presets.items()} == {"scapo": "cpu/epochs-2-2",
                                                                "npcs": "cpu/epochs-6"}
    assert (presets["scapo"][0].stage1_epochs, presets["scapo"][0].stage2_epochs) == (2, 2)

    for seed, preset, finished in ((0, "cpu/epochs-2-2", True), (1, "cpu/epochs-2-2", False),
                                   (2, "cpu/epochs-9-9", True)):
        run = data / f"run_{Cell('scapo', 'laptop', seed, preset).run_key}"
        run.mkdir(parents=True)
        (run / "checkpoint.pt").write_bytes(b"weights")
        if finished:
            (run / "timing.json").write_text("{}")
    work = tmp_path / "compute" / "b1"
    for seed in (0, 1, 2):
        _reuse_table_run(data, work, "laptop", "paper", "scapo", seed, "cpu/epochs-2-2")
    cells = cells_dir(work, "laptop", "paper")
    assert (cells / "scapo_s0_run" / "checkpoint.pt").read_bytes() == b"weights"
    assert not (cells / "scapo_s1_run").exists() and not (cells / "scapo_s2_run").exists()
    assert "reusing the table's finished run" in capsys.readouterr().out
    (cells / "scapo_s0_run" / "checkpoint.pt").write_bytes(b"resumed")  # a cell's own run is never replaced
    _reuse_table_run(data, work, "laptop", "paper", "scapo", 0, "cpu/epochs-2-2")
    assert (cells / "scapo_s0_run" / "checkpoint.pt").read_bytes() == b"resumed"

    from scapo.bench.compute import write_curve

    rec = {"method": "scapo", "budget_min": 1.0, "seed": 0, "wall": {"train_steps": 6}, "provenance": {"commit": "c"},
           "dataset_hash": "h", "budget_values": {"preset": "cpu/epochs-2-2"}, "frame_consistency_sym": 0.5,
           "S": 80.0, "R_sym_median": 5.0}
    meta = {"name": "curve", "category": "laptop", "rung": "paper", "split": "val", "dataset": data.name,
            "instances": 10, "views": 2, "train_views": 4, "data_seed": 0, "preset": "cpu", "protocol": "scapo",
            "command": "scapo bench compute --from-table", "from_table": True}
    write_curve([rec], tmp_path / "o", meta)
    assert "presets scapo cpu (the table's" in (tmp_path / "o" / "curve.md").read_text()
    # a curve finished on another machine names each cell's machine, apart from the writer's
    other = {**rec, "budget_min": 2.0, "provenance": {"commit": "c", "device": "cpu: 2 cores, B"}}
    rec["provenance"]["device"] = "cpu: 2 cores, A"
    write_curve([rec, rec | {"budget_min": 3.0}, other], tmp_path / "o", {**meta, "machine": "cpu: 2 cores, B"})
    assert ("cells computed on cpu: 2 cores, A (2 cells); cpu: 2 cores, B (1 cell); written on cpu: 2 cores, B by"
            in (tmp_path / "o" / "curve.md").read_text())
    with pytest.raises(ConfigError, match="not a finished dataset.*bench table1 --data-only"):
        _table_dataset(tmp_path, "laptop", "paper", 10, 2, 4, 0, rung_config("laptop", "paper", 10, 2, 4, 0))
