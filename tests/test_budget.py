"""The equal training budget of the tables (``scapo bench table1 --budget-minutes``) and the schedule part of the
preset grammar it names its cells' presets with."""

import json

import pytest

from scapo.errors import ConfigError, UnknownNameError


def test_schedule_part_of_a_preset_name():
    """``epochs-A-B`` sets a two-stage preset's stages, ``epochs-N`` a one-stage one's epochs; a schedule the method
    has no fields for, or a count of 0, is refused; the name round-trips through ``schedule_part``."""
    from scapo.methods import METHODS
    from scapo.registry import parse_preset, schedule_part

    parsed = parse_preset("cpu/sj/epochs-3-2")
    assert parsed.schedule == {"epochs": (3, 2)} and parsed.rest == () and parsed.supervision == "SJ"
    scapo = METHODS.get("scapo").preset("cpu/epochs-3-2")
    assert (scapo.stage1_epochs, scapo.stage2_epochs, scapo.name) == (3, 2, "cpu/epochs-3-2")
    assert METHODS.get("scapo").preset("cpu/no-shape_var/epochs-4-1").losses.disabled == ("shape_var",)
    npcs = METHODS.get("npcs").preset("cpu/epochs-7")
    assert npcs.epochs == 7 and npcs.name == "cpu/epochs-7"
    assert METHODS.get("op-align").preset("cpu/sj/epochs-5").supervision == "SJ"
    with pytest.raises(UnknownNameError, match="epochs-N"):
        METHODS.get("op-align").preset("cpu/epochs-7-3")
    with pytest.raises(UnknownNameError, match="epochs-STAGE1-STAGE2"):
        METHODS.get("scapo").preset("cpu/epochs-7")
    with pytest.raises(UnknownNameError, match="at least 1"):
        METHODS.get("npcs").preset("cpu/epochs-0")
    assert schedule_part({"stage1_epochs": 15, "stage2_epochs": 13}) == "epochs-15-13"
    assert schedule_part({"epochs": 47}) == "epochs-47" and schedule_part({"iterations": 400}) == "iterations-400"


def _speed(work, data_name, method, row):
    path = work / "speeds" / f"{data_name}_{method}_cpu.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps([row]))


def test_budget_cells_fill_the_budget_less_the_one_time_work(tmp_path):
    """Hand-built speeds (16 clouds/s at batch 16: one step a second; 160 training clouds: 10 steps an epoch): NPCS's
    10 epochs take 100 s, so 1 core-minute buys 6 epochs, 60 steps; with 30 s of one-time work it buys exactly 30
    steps fewer (3 epochs); SCAPO's 10 + 10 take 200 s, so 3 + 3. A fitted method is left alone; one-time work longer
    than the budget, or no measured speed with measuring off, is refused clearly."""
    from scapo.bench.cells import Cell
    from scapo.bench.experiments import budget_cells, dataset_dir
    from scapo.bench.perf import training_budget

    kw = {"viewpoints": "paper", "train_views": 4}
    name = dataset_dir(tmp_path, "laptop", 10, 2, 0, kw).name
    base = {"batch_size": 16, "fixed_s": 0.0, "train_clouds": 160, "max_steps_per_epoch": 0, "stage1_epoch_s": 0.0,
            "stage1_clouds_per_s": 16.0}
    npcs = {**base, "method": "npcs", "stage1_epochs": 10, "iterations": 0}
    free, charged = training_budget([npcs, {**npcs, "fixed_s": 30.0}], 1.0, 160)
    assert (free["stage1_steps_for_budget"], charged["stage1_steps_for_budget"]) == (60, 30)
    _speed(tmp_path, name, "npcs", npcs)
    _speed(tmp_path, name, "scapo", {**base, "method": "scapo", "stage1_epochs": 10, "stage2_epochs": 10,
                                     "stage2_clouds_per_s": 16.0, "stage2_epoch_s": 0.0})
    cells = [Cell("npcs", "laptop", 0, "cpu"), Cell("scapo", "laptop", 1, "cpu"), Cell("icp", "laptop")]
    out, schedules, plans = budget_cells(cells, 1.0, tmp_path, 10, 2, 0, kw, measure=False)
    assert [c.preset for c in out] == ["cpu/epochs-6", "cpu/epochs-3-3", None]
    assert schedules == {"laptop": {"npcs cpu": "epochs-6", "scapo cpu": "epochs-3-3"}}
    assert out[1].key == "scapo_cpu+epochs-3-3_s1"
    plan = plans[("laptop", out[1].key)]  # what the cell's ledger is held to: 3 + 3 epochs of 10 one-second steps
    assert plan["budget_s"] == 60.0 and plan["phases"] == {"stage1/steps": 30.0, "stage1/epochs": 0.0,
                                                           "stage2/steps": 30.0, "stage2/epochs": 0.0}
    # a one-time cost longer than the budget (EAP-style's joint estimation on a large split) is refused, not excused
    _speed(tmp_path, name, "npcs", {**npcs, "fixed_s": 500.0})
    with pytest.raises(ConfigError, match="one-time work alone is 500 charged seconds"):
        budget_cells(cells[:1], 1.0, tmp_path, 10, 2, 0, kw, measure=False)
    with pytest.raises(ConfigError, match="not measured yet"):
        budget_cells([Cell("eap", "laptop", 0, "cpu")], 1.0, tmp_path, 10, 2, 0, kw, measure=False)
    with pytest.raises(ConfigError, match="budget-minutes"):
        budget_cells(cells, 0.0, tmp_path, 10, 2, 0, kw, measure=False)


def test_a_cell_over_its_budget_is_refused_naming_the_phase():
    """:func:`scapo.engine.ledger.check_budget`: within 110 % of the budget a ledger passes; beyond it the cell is
    refused, naming the phase that overran its plan the most."""
    from scapo.engine.ledger import Ledger, check_budget

    led = Ledger()
    led.add("setup", 5.0, 5.0)
    led.add("stage2/start", 40.0, 41.0)
    led.add("stage1/steps", 60.0, 61.0)
    plan = {"setup": 5.0, "stage2/start": 10.0, "stage1/steps": 60.0}
    check_budget(led.to_dict(), 100.0, plan)  # 105 core-seconds: within 110 %
    led.add("stage2/start", 10.0, 10.0)
    with pytest.raises(ConfigError, match=r"charged 115 core-seconds.*'stage2/start' took 50 s against 10 s planned"):
        check_budget(led.to_dict(), 100.0, plan, what="cell laptop/paper/scapo_s0")
    with pytest.raises(ConfigError, match="the largest phase is 'stage1/steps'"):
        check_budget(led.to_dict(), 100.0)
    two = Ledger(world=2)  # two processes (torchrun): rank 0 keeps the ledger, every rank's seconds are charged
    two.add("stage1/steps", 3.0, 4.0)
    assert two.charged("stage1/steps") == 6.0 and two.to_dict()["phases"]["stage1/steps"]["wall_s"] == 8.0
    gpu = Ledger(accelerator=True, before=led.to_dict())  # a resumed run adds to its checkpoint's ledger
    gpu.add("stage1/steps", 0.0, 1.0)
    assert gpu.to_dict()["unit"] == "device-seconds" and gpu.charged("stage1/steps") == pytest.approx(62.0)


def test_ladder_on_a_device_keeps_its_cells_and_speeds_apart(tmp_path):
    """The CPU ladder's files keep their names; another preset or a device gets its own speed file and cell folder."""
    from scapo.bench.ladder import cells_dir, speed_file

    assert speed_file(tmp_path, "scapo").name == "speed_scapo.json"
    assert speed_file(tmp_path, "scapo", "paper", "cuda").name == "speed_scapo_paper_cuda.json"
    assert speed_file(tmp_path, "npcs", "test").name == "speed_npcs_test_cpu.json"
    assert cells_dir(tmp_path, "laptop", "paper") == tmp_path / "laptop" / "paper"
    assert cells_dir(tmp_path, "laptop", "paper", "paper", "cuda:0") == tmp_path / "laptop" / "paper" / "paper_cuda0"


def test_source_commit_of_a_copy_without_git(tmp_path, monkeypatch):
    """A copy of a checkout without ``.git`` names the commit the caller states (``<sha>-copy``), a malformed one
    is ignored."""
    import scapo.provenance as prov

    monkeypatch.setattr(prov, "__file__", str(tmp_path / "scapo" / "provenance.py"))
    prov.git_commit.cache_clear()
    try:
        monkeypatch.setenv("SCAPO_SOURCE_COMMIT", "ab" * 20)
        assert prov.git_commit() == "ab" * 20 + "-copy"
        prov.git_commit.cache_clear()
        monkeypatch.setenv("SCAPO_SOURCE_COMMIT", "not-a-sha")
        assert prov.git_commit().startswith("v")
    finally:
        prov.git_commit.cache_clear()


def test_a_schedule_part_that_is_not_one_says_how_to_write_it():
    """``test/epochs-abc`` was refused as "not 'no-TERM'"; it is named as a schedule, with the forms it takes."""
    from scapo.errors import UnknownNameError
    from scapo.methods import METHODS

    for method in ("scapo", "npcs"):
        with pytest.raises(UnknownNameError, match=r"'epochs-abc' is not a schedule; write epochs-N \(one stage\), "
                                                   r"epochs-N-M \(two stages\) or iterations-N"):
            METHODS.get(method).preset("test/epochs-abc")


def test_the_ledger_charges_the_cpu_seconds_of_child_processes():
    """Work handed to a subprocess is the method's work too (``torch.compile`` runs the C++ compiler as child
    processes): a phase that waits on a child busy for about 0.4 CPU seconds is charged them, though this process
    only waited."""
    import subprocess
    import sys

    from scapo.engine.ledger import Ledger

    ledger = Ledger()
    with ledger.phase("stage1/compile"):
        subprocess.run([sys.executable, "-c", "import time\nt = time.process_time()\n"
                        "while time.process_time() - t < 0.4: pass"], check=True)
    assert ledger.charged("stage1/compile") >= 0.35


def test_budget_cells_keep_their_speeds_with_the_archive_and_measure_again_on_another_cpu_kind(tmp_path,
                                                                                             monkeypatch, capsys):
    """The tables' budget plans from speeds this machine can plan from (:func:`scapo.bench.ladder.measured_speed`, as
    the ladder): a speed file of another kind of CPU is kept aside and measured again; with ``--archive`` the speed
    files are kept beside the cells and restored into a new work folder, so a table resumed on a new machine (or
    written with ``--finished-only``) names its cells' schedules as they were planned."""
    import scapo.bench.perf as perf
    from scapo.bench.cells import Cell
    from scapo.bench.experiments import budget_cells, dataset_dir
    from scapo.provenance import cpu_kind

    kw = {"viewpoints": "paper", "train_views": 4}
    data = dataset_dir(tmp_path / "w", "laptop", 10, 2, 0, kw)
    data.mkdir(parents=True)
    monkeypatch.setattr("scapo.data.load", lambda d, split: [None] * 160)  # 160 training clouds, nothing rendered
    row = {"batch_size": 16, "fixed_s": 0.0, "train_clouds": 160, "max_steps_per_epoch": 0, "stage1_epoch_s": 0.0,
           "stage1_clouds_per_s": 16.0, "method": "npcs", "stage1_epochs": 10, "iterations": 0, "unit": "core-seconds",
           "data": str(data), "wall_per_cpu": 1.0, "steps_cpu_s": 60.0}
    calls = []
    monkeypatch.setattr(perf, "bench_train_data", lambda *a, **k: calls.append(k) or [{**row, "cpu_kind": cpu_kind()}])
    _speed(tmp_path / "w", data.name, "npcs", {**row, "cpu_kind": "Other CPU, family 1 model 2, avx2"})
    cells = [Cell("npcs", "laptop", 0, "cpu")]
    out, _, _ = budget_cells(cells, 1.0, tmp_path / "w", 10, 2, 0, kw, archive=tmp_path / "a")
    assert "was measured on another kind of CPU (Other CPU, family 1 model 2, avx2" in capsys.readouterr().out
    assert len(calls) == 1 and out[0].preset == "cpu/epochs-6"
    speeds = sorted(p.name for p in (tmp_path / "a" / "speeds").iterdir())
    assert len(speeds) == 2 and any(n.endswith(".other-cpu.json") for n in speeds)  # both kept beside the cells
    # a new work folder: the archived speed is restored and reused, nothing measured
    data2 = dataset_dir(tmp_path / "w2", "laptop", 10, 2, 0, kw)
    data2.mkdir(parents=True)
    archived = json.loads((tmp_path / "a" / "speeds" / f"{data.name}_npcs_cpu.json").read_text())
    (tmp_path / "a" / "speeds" / f"{data.name}_npcs_cpu.json").write_text(
        json.dumps([{**r, "data": str(data2)} for r in archived]))
    out2, _, _ = budget_cells(cells, 1.0, tmp_path / "w2", 10, 2, 0, kw, archive=tmp_path / "a")
    assert len(calls) == 1 and out2[0].preset == "cpu/epochs-6"
    out3, _, _ = budget_cells(cells, 1.0, tmp_path / "w3", 10, 2, 0, kw, measure=False, archive=tmp_path / "a")
    assert out3[0].preset == "cpu/epochs-6"  # --finished-only on a machine that never measured
