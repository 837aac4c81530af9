"""``scapo bench table1 / table3``: cells computed once, resumable, dry run, identical tables on rerun."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scapo.bench import Cell, parse_category_seeds, run_table1, run_table3, table1_cells, table3_cells
from scapo.errors import ConfigError, UnknownNameError

# tests run from any checkout; the "+refine" rows have their own test; the figures (seconds of matplotlib each time
# a table is written) are drawn and checked once, by the ``bench`` fixture
#: Tables 1 and 3 on the whole sphere (their datasets named as before the paper's viewpoints existed; the paper's
#: setting has a test of its own); Table 2 takes no viewpoints (``SMALL_T2``).
SMALL = dict(instances=10, views=2, preset="test", progress=False, allow_dirty=True, refine_rows=False, figures=False,
             viewpoints="sphere")
SMALL_T2 = {k: v for k, v in SMALL.items() if k != "viewpoints"}


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """Table 1 with NPCS-style and SCAPO (test presets, one seed) on a tiny laptop dataset."""
    root = tmp_path_factory.mktemp("bench")
    work, out = root / "work", root / "results"
    plan = run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=out, seeds=[0], dry_run=True, **SMALL)
    assert not work.exists() and not out.exists()
    results = run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=out, seeds=[0],
                         **{**SMALL, "figures": True})
    return work, out, plan, results


def _same(a, b) -> bool:
    """Equal summaries (NaN equal to NaN, as the tables print them)."""
    return [json.dumps(r.summary, sort_keys=True) for r in a] == [json.dumps(r.summary, sort_keys=True) for r in b]


def _forbid(monkeypatch, *names):
    import scapo.bench.cells as cells

    def boom(*a, **k):
        raise AssertionError("a finished cell was recomputed")

    for n in names:
        monkeypatch.setattr(cells, n, boom)


def test_dry_run_lists_every_cell_and_computes_nothing(bench):
    work, out, plan, _ = bench
    assert [(r["key"], r["status"]) for r in plan] == [("npcs_test_s0", "todo"), ("scapo_test_s0", "todo")]
    assert all(r["dataset"] == "to generate" for r in plan)
    after = run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=out, seeds=[0, 1], dry_run=True, **SMALL)
    assert {r["key"]: r["status"] for r in after} == {"npcs_test_s0": "done", "npcs_test_s1": "todo",
                                                     "scapo_test_s0": "done", "scapo_test_s1": "todo"}
    assert all(r["seconds"] > 0 for r in after if r["status"] == "done")


def test_tables_figures_and_per_cell_provenance(bench):
    work, out, _, results = bench
    assert [r.method for r in results] == ["npcs", "scapo"]
    for suffix in ("csv", "md", "tex", "json"):
        assert (out / f"table1_synthetic_sphere.{suffix}").stat().st_size > 0
    assert (out / "table1_synthetic_sphere_laptop.png").stat().st_size > 4_000  # drawn (a blank 256-colour PNG is about 1 KB)
    assert (out / "table1_synthetic_sphere_errors.png").stat().st_size > 4_000  # drawn (a blank 256-colour PNG is about 1 KB)
    assert (out / "table1_synthetic_sphere_summary.png").stat().st_size > 4_000  # the table at a glance
    prov = json.loads((out / "table1_synthetic_sphere.json").read_text())["provenance"]
    assert prov["preset"] == "test" and prov["protocol"] == "scapo" and prov["training_seeds"] == {"laptop": [0]}
    assert len(prov["datasets"]["laptop"]) == 16
    cells = {c["cell"]: c for c in prov["cells"]}
    assert set(cells) == {"npcs_test_s0", "scapo_test_s0"}
    for key, c in cells.items():
        timing = json.loads((work / "laptop_i10_v2_s0" / f"run_{key}" / "timing.json").read_text())
        assert c["train_s"] == timing["seconds"]  # training time summed over the run's sessions
        with open(work / "laptop_i10_v2_s0" / f"run_{key}" / "log.csv") as f:
            assert c["train_steps"] == timing["steps"] == sum(1 for _ in f) - 1  # one log row per optimiser step
        assert c["predict_s"] > 0 and c["evaluate_s"] > 0 and c["commit"] and c["device"].startswith("cpu")
        assert c["run"] == f"run_{key}"
        # the compute ledger: every charged core-second of the run, by phase, summing to the charged total
        assert c["charged_s"] == pytest.approx(sum(p["charged_s"] for p in timing["ledger"]["phases"].values()),
                                               abs=0.01)
        assert {"setup", "stage1/steps"} <= set(timing["ledger"]["phases"]) and c["infer_ms_per_cloud"] > 0
        phases = timing["ledger"]["phases"]  # one session: the phases' wall seconds are the set-up and the loop's
        assert sum(p["wall_s"] for p in phases.values()) - phases["setup"]["wall_s"] == pytest.approx(
            timing["session_s"], abs=0.01)
    assert prov["compute_hours"] == round(sum(c["train_s"] + c["predict_s"] + c["evaluate_s"]
                                              for c in cells.values()) / 3600, 2)
    from scapo.methods import METHODS

    rec = json.loads((work / "laptop_i10_v2_s0" / "cells" / "scapo_test_s0.scapo.json").read_text())
    assert rec["info"]["inference"] == METHODS.get("scapo").inference(work / "laptop_i10_v2_s0" / "run_scapo_test_s0")
    md = (out / "table1_synthetic_sphere.md").read_text()
    assert "## Cells (wall time, minutes; training steps; charged compute" in md and "scapo_test_s0" in md and "SCAPO (paper)" in md


def test_rerun_recomputes_nothing_and_rewrites_identical_tables(bench, monkeypatch):
    work, out, _, results = bench
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    _forbid(monkeypatch, "train_method", "run_method", "evaluate")
    again = run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=out, seeds=[0], **SMALL)
    assert _same(again, results)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_changed_evaluator_re_evaluates_without_retraining_or_predicting(bench, monkeypatch, tmp_path, capsys):
    """Only the evaluation is redone; the record keeps the commit that trained and predicted the cell beside the
    evaluation's, and a cell computed at a -dirty commit stays flagged after a clean re-evaluation."""
    import scapo.bench.cells as cells
    from scapo import provenance

    work, _, _, results = bench
    path = work / "laptop_i10_v2_s0" / "cells" / "npcs_test_s0.scapo.json"
    per_sample = path.with_suffix(".parquet")
    saved = {p: p.read_bytes() for p in (path, per_sample)}  # the shared fixture is put back afterwards
    try:
        rec = json.loads(path.read_text())
        predict_s = rec["wall"]["predict_s"]
        rec["provenance"]["commit"] = "0123456789abcdef-dirty"  # as if trained from uncommitted code
        rec.pop("computed_commit", None)  # a record written before the field existed
        path.write_text(json.dumps(rec))
        _forbid(monkeypatch, "run_method")
        monkeypatch.setattr(cells, "evaluator_fingerprint", lambda: "changed")
        monkeypatch.setattr(cells, "provenance",
                            lambda **kw: {**provenance.provenance(**kw), "commit": "fedcba9876543210"})
        out = tmp_path / "out"
        again = run_table1(["npcs"], ["laptop"], work_dir=work, out_dir=out, seeds=[0], **SMALL)
        assert _same(again[:1], results[:1])  # same predictions, same evaluator code: same scores
        rec = json.loads(path.read_text())
        assert rec["evaluator"] == "changed" and rec["provenance"]["commit"] == "fedcba9876543210"
        assert rec["computed_commit"] == "0123456789abcdef-dirty"
        assert rec["wall"]["predict_s"] == predict_s  # the predictions' wall time as measured when they were made
        prov = json.loads((out / "table1_synthetic_sphere.json").read_text())["provenance"]
        assert prov["cells"][0]["commit"] == "0123456789abcdef-dirty"
        assert prov["cells"][0]["evaluated_at"] == "fedcba9876543210"
        assert prov["commits"] == ["0123456789abcdef-dirty", "fedcba9876543210"]
        assert "0123456789ab-dirty (evaluated fedcba987654)" in (out / "table1_synthetic_sphere.md").read_text()
        capsys.readouterr()
        plan = run_table1(["npcs"], ["laptop"], work_dir=work, out_dir=None, seeds=[0], dry_run=True, **SMALL)
        assert plan[0]["status"] == "done" and "(computed at 0123456789ab-dirty" in capsys.readouterr().out
        assert cells.dirty_commit(rec)
        _forbid(monkeypatch, "evaluate")  # the same evaluator again: a valid record, nothing recomputed
        run_table1(["npcs"], ["laptop"], work_dir=work, out_dir=None, seeds=[0], **SMALL)
        assert json.loads(path.read_text()) == rec
    finally:
        for p, b in saved.items():
            p.write_bytes(b)


def test_a_moved_work_folder_keeps_its_predictions_and_the_plan_says_what_compute_does(bench, monkeypatch, tmp_path):
    """A work folder copied elsewhere is only scored under a new protocol (its predictions name their run by folder,
    not by absolute path), as its dry run says; predictions made under other inference settings are planned as
    "predict", which is what computing the cell does."""
    import shutil

    from scapo.eval import Predictions

    work, _, _, _ = bench
    copy = tmp_path / "moved"
    shutil.copytree(work, copy)
    plan = run_table1(["npcs", "scapo"], ["laptop"], work_dir=copy, out_dir=None, seeds=[0], dry_run=True,
                      protocol="eap", **SMALL)
    assert [r["status"] for r in plan] == ["evaluate", "evaluate"]
    timing = (copy / "laptop_i10_v2_s0" / "run_scapo_test_s0" / "timing.json").read_bytes()
    _forbid(monkeypatch, "run_method")
    run_table1(["npcs", "scapo"], ["laptop"], work_dir=copy, out_dir=None, seeds=[0], protocol="eap", **SMALL)
    assert (copy / "laptop_i10_v2_s0" / "run_scapo_test_s0" / "timing.json").read_bytes() == timing  # not trained
    assert (copy / "laptop_i10_v2_s0" / "cells" / "scapo_test_s0.eap.json").is_file()
    path = copy / "laptop_i10_v2_s0" / "predictions_scapo_test_s0.npz"
    preds = Predictions.load(path)
    preds.info["inference"] = {"refine": "other settings"}
    preds.save(path)
    plan = run_table1(["scapo"], ["laptop"], work_dir=copy, out_dir=None, seeds=[0], dry_run=True, protocol="op-align",
                      **SMALL)
    assert [r["status"] for r in plan] == ["predict"]


def test_a_lost_work_folder_is_restored_from_the_cells_archive(bench, monkeypatch, tmp_path):
    """Issue 31's cells outlive their machine: the archive keeps each done cell's record (with its predictions'
    sha256), per-sample metrics and run identity, not its predictions (most of an archive's size; reproducible); a
    fresh work folder whose dataset has the same hash gets the cells back and writes the same table computing
    nothing, and one of another dataset gets nothing. With ``archive_predictions`` the predictions are kept too and
    come back byte for byte."""
    import shutil

    from scapo.bench.archive import restore_cells

    work, out, _, results = bench
    archive = tmp_path / "archive"
    first = run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=None, seeds=[0], archive=archive,
                       **SMALL)  # done cells are archived as the bench meets them
    assert _same(first, results)
    kept = archive / "laptop_i10_v2_s0"
    stems = sorted(f"{m}_test_s0.{p}" for m in ("npcs", "scapo") for p in ("eap", "op-align", "scapo"))
    assert sorted(p.name for p in (kept / "cells").iterdir()) == sorted(  # scored under each archived protocol
        [f"{stem}.json" for stem in stems] + ["per_sample.parquet"])  # every cell's per-sample metrics in one file
    import pandas as pd

    from scapo.bench.archive import archived_per_sample, same_as_archived

    for stem in stems:  # each cell's own table comes back from the packed file (floats within float32 rounding)
        own = pd.read_parquet(work / "laptop_i10_v2_s0" / "cells" / f"{stem}.parquet")
        assert same_as_archived(archived_per_sample(kept / "cells", stem), own)
    assert sorted(p.name for p in (kept / "run_scapo_test_s0").iterdir()) == ["run.json", "timing.json"]
    original = work / "laptop_i10_v2_s0" / "predictions_scapo_test_s0.npz"
    assert not list(kept.glob("predictions_*"))  # their sha256 is in the records
    with_preds = tmp_path / "archive_with_predictions"
    run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=None, seeds=[0], archive=with_preds,
               archive_predictions=True, **SMALL)
    assert (with_preds / kept.name / "predictions_scapo_test_s0.npz.xz").stat().st_size < original.stat().st_size
    # a fresh machine: the dataset generated again (here: copied without the runs, predictions and records)
    fresh = tmp_path / "fresh"
    shutil.copytree(work / "laptop_i10_v2_s0", fresh / "laptop_i10_v2_s0",
                    ignore=shutil.ignore_patterns("run_*", "predictions_*", "cells", "stale", "dirty"))
    for work_dir in (fresh, tmp_path / "not generated yet"):  # the dry run says what the bench will restore
        plan = run_table1(["npcs", "scapo"], ["laptop"], work_dir=work_dir, out_dir=None, seeds=[0], dry_run=True,
                          archive=archive, **SMALL)
        assert [r["status"] for r in plan] == ["restore", "restore"] and all(r["seconds"] > 0 for r in plan)
    _forbid(monkeypatch, "train_method", "run_method", "evaluate")
    again = run_table1(["npcs", "scapo"], ["laptop"], work_dir=fresh, out_dir=tmp_path / "out", seeds=[0],
                       archive=archive, **SMALL)
    assert _same(again, results)
    assert not (fresh / "laptop_i10_v2_s0" / original.name).exists()  # tabled from its record and per-sample metrics
    assert json.loads((tmp_path / "out" / "table1_synthetic_sphere.json").read_text())["provenance"]["cells"] == \
        json.loads((out / "table1_synthetic_sphere.json").read_text())["provenance"]["cells"]
    assert (tmp_path / "out" / "table1_synthetic_sphere.md").is_file()
    eap = run_table1(["npcs", "scapo"], ["laptop"], work_dir=fresh, out_dir=tmp_path / "out_eap", seeds=[0],
                     archive=archive, protocol="eap", name="t_eap", **SMALL)  # another protocol: from the archive too
    assert len(eap) == 2 and (tmp_path / "out_eap" / "t_eap.md").is_file()
    kept_preds = tmp_path / "fresh_kept"
    shutil.copytree(work / "laptop_i10_v2_s0", kept_preds / "laptop_i10_v2_s0",
                    ignore=shutil.ignore_patterns("run_*", "predictions_*", "cells", "stale", "dirty"))
    assert _same(run_table1(["npcs", "scapo"], ["laptop"], work_dir=kept_preds, out_dir=None, seeds=[0],
                            archive=with_preds, **SMALL), results)
    assert (kept_preds / "laptop_i10_v2_s0" / original.name).read_bytes() == original.read_bytes()
    # another dataset under the same folder name restores nothing, and a restore never overwrites
    other = tmp_path / "other" / "laptop_i10_v2_s0"
    other.mkdir(parents=True)
    assert restore_cells(other, archive, "another dataset hash") == []
    from scapo.data import load

    done = fresh / "laptop_i10_v2_s0"
    assert restore_cells(done, archive, load(done, "test").dataset_hash) == []  # its records are there already


def _generated_elsewhere(src: Path, dst: Path, field: str, change) -> str:
    """A copy of the dataset ``src`` in ``dst`` as another CPU kind would generate it: ``change`` applied to
    ``field`` of its first shard, the shard's record appended to the journal and the card written again, as
    ``generate`` does; returns the changed shard's name."""
    import io
    import shutil

    import numpy as np

    from scapo.data import generate
    from scapo.data.config import GenerateConfig
    from scapo.data.generate import JOURNAL, config_sha256
    from scapo.data.storage import sha256_file

    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("run_*", "predictions_*", "cells", "stale", "dirty"))
    card = json.loads((dst / "card.json").read_text())
    name = sorted(card["shards"])[0]
    path = dst / "shards" / f"{name}.npz"
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[field] = change(arrays[field])
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())
    cfg = GenerateConfig.from_dict(card["config"])
    with open(dst / JOURNAL, "a") as f:
        f.write(json.dumps({"shard": name, "sha256": sha256_file(path), "config_sha256": config_sha256(cfg)}) + "\n")
    generate(cfg, dst, progress=False)
    return name


def test_a_dataset_generated_on_another_cpu_is_made_the_archived_one_and_its_cells_restored(bench, monkeypatch,
                                                                                           tmp_path, capsys):
    """Issue 31's datasets differ across CPU kinds in the last bit of some double-precision ground truth, so a
    fresh machine of another kind regenerated datasets of other hashes and restored no cell. The archive pins each
    dataset's bytes: a regenerated dataset that differs only so is re-written to the archived bytes (every shard's
    sha256 checked) and its cells are restored; a larger difference, or one in the rendered points, changes nothing
    and its cells are computed again. Cells archived before the pinning pin only their own dataset."""
    import numpy as np

    from scapo.bench.archive import archive_conflict, archive_dataset, reconcile_dataset
    from scapo.data import load
    from scapo.errors import DatasetError

    work, out, _, results = bench
    archive = tmp_path / "archive"
    run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=None, seeds=[0], archive=archive, **SMALL)
    data = work / "laptop_i10_v2_s0"
    pinned = archive / "laptop_i10_v2_s0" / "dataset"
    assert sorted(p.name for p in pinned.iterdir()) == ["card.json", "double.npz.xz", "fields.json"]
    assert archive_dataset(data, archive) == "same"
    want = load(data, "test").dataset_hash
    # another CPU: one camera pose's last bit differs, so the shard, and the dataset hash, differ
    fresh = tmp_path / "fresh" / data.name
    shard = _generated_elsewhere(data, fresh, "T_cam_obj", lambda a: np.nextafter(a, 2 * a + 1))
    assert load(fresh, "test").dataset_hash != want
    assert archive_dataset(fresh, archive) == "other"  # the archive keeps the dataset its cells were computed on
    _forbid(monkeypatch, "train_method", "run_method", "evaluate")
    again = run_table1(["npcs", "scapo"], ["laptop"], work_dir=fresh.parent, out_dir=None, seeds=[0],
                       archive=archive, **SMALL)
    assert _same(again, results)
    assert "made the archived dataset" in capsys.readouterr().out
    assert load(fresh, "test").dataset_hash == want
    assert (fresh / "shards" / f"{shard}.npz").read_bytes() == (data / "shards" / f"{shard}.npz").read_bytes()
    report = json.loads((fresh / "reconciled.json").read_text())
    assert report["shards"] == 1 and 0 < report["max_abs_diff"]["T_cam_obj"] < 1e-12
    assert reconcile_dataset(fresh, archive)["status"] == "same"
    # npcs is float32 derived from double-precision poses: one ulp off where a pose's rounding crossed a float32
    # boundary (washer, issue 31); it is computed again from the archived poses and must give the archived bytes
    ulp = tmp_path / "ulp" / data.name
    _generated_elsewhere(data, ulp, "npcs", lambda a: np.where(a != 0, np.nextafter(a, np.float32(9)), a))
    rep = reconcile_dataset(ulp, archive)
    assert rep["status"] == "reconciled" and rep["recomputed"] == {"npcs": 1}, rep
    assert 0 < rep["max_abs_diff"]["npcs"] < 1e-6 and load(ulp, "test").dataset_hash == want
    # more than rounding, or a difference in the rendered points: left as generated, nothing restored
    others = {}
    for field, change, why in (("joint_state", lambda a: a + 1e-6, "more than rounding"),
                               ("npcs", lambda a: np.where(a != 0, a + np.float32(1e-3), a),
                                "more than float32 rounding"),
                               ("points", lambda a: np.nextafter(a, np.float32(9)), "not double-precision")):
        other = others[field] = tmp_path / field / data.name
        _generated_elsewhere(data, other, field, change)
        before = load(other, "test").dataset_hash
        rep = reconcile_dataset(other, archive)
        assert rep["status"] == "different" and why in rep["why"], rep
        assert load(other, "test").dataset_hash == before and not (other / "reconciled.json").exists()
        plan = run_table1(["npcs", "scapo"], ["laptop"], work_dir=other.parent, out_dir=None, seeds=[0],
                          dry_run=True, archive=archive, **SMALL)
        assert [r["status"] for r in plan] == ["todo", "todo"]
    # a damaged archive is a clear error, not a silent restore: values that are not the ones digested, unreadable
    import io
    import lzma

    good = (pinned / "double.npz.xz").read_bytes()
    with np.load(io.BytesIO(lzma.decompress(good))) as z:
        values = {k: z[k] for k in z.files}
    values[f"{shard}/joint_state"] = values[f"{shard}/joint_state"] * (1 + 1e-12)
    buf = io.BytesIO()
    np.savez(buf, **values)
    (pinned / "double.npz.xz").write_bytes(lzma.compress(buf.getvalue()))
    with pytest.raises(DatasetError, match="do not match their digest"):
        reconcile_dataset(others["joint_state"], archive)
    (pinned / "double.npz.xz").write_bytes(b"not xz")
    broken = others["points"]
    with pytest.raises(DatasetError, match="cannot be read"):
        reconcile_dataset(broken, archive)
    # cells archived before datasets were pinned: only their own dataset is pinned, never another machine's
    import shutil

    legacy = tmp_path / "legacy"
    shutil.copytree(archive / data.name / "cells", legacy / data.name / "cells")
    assert archive_dataset(broken, legacy) == "unpinned cells" and not (legacy / data.name / "dataset").exists()
    assert "which is not pinned" in archive_conflict(broken, legacy) and archive_conflict(data, legacy) == ""
    assert archive_dataset(data, legacy) == "archived"
    assert "could not make it the pinned" in archive_conflict(broken, legacy) and archive_conflict(data, legacy) == ""
    assert archive_conflict(broken, tmp_path / "empty archive") == ""


def test_data_only_prepares_datasets_and_computes_no_cell(monkeypatch, tmp_path, capsys):
    from scapo.data import load

    _forbid(monkeypatch, "train_method", "run_method", "evaluate")
    archive = tmp_path / "archive"
    out = run_table1(["icp"], ["laptop"], work_dir=tmp_path / "work", out_dir=tmp_path / "out", seeds=[0],
                     archive=archive, data_only=True, **{**SMALL, "instances": 4})
    data = tmp_path / "work" / "laptop_i4_v2_s0"
    assert out == [] and not (tmp_path / "out" / "table1_synthetic_sphere.json").exists()
    assert not (data / "cells").exists()
    pinned = json.loads((archive / data.name / "dataset" / "card.json").read_text())
    assert pinned["dataset_hash"] == load(data, "test").dataset_hash
    assert "pinned in the archive" in capsys.readouterr().out
    with pytest.raises(ConfigError, match="--data-only"):
        run_table1(["icp"], ["laptop"], work_dir=tmp_path / "work", out_dir=None, seeds=[0], data_only=True,
                   finished_only=True, **{**SMALL, "instances": 4})


def test_the_evaluator_fingerprint_is_the_code_this_process_loaded(monkeypatch):
    """A bench runs for hours: a checkout changed under it must not make its records claim the new evaluator."""
    import scapo.bench.cells as cells

    first = cells.evaluator_fingerprint()
    monkeypatch.setattr(Path, "read_bytes", lambda self: b"edited on disk since")
    assert cells.evaluator_fingerprint() == first
    assert cells._hash_evaluator_source() != first  # what a fresh process would record


def test_table3_reuses_table1s_scapo_cell_and_names_the_ablations(bench, monkeypatch):
    work, out, _, results = bench
    res = run_table3(["laptop"], work_dir=work, out_dir=out, seeds=[0], ablations=["shape_var"], **SMALL)
    assert [r.method for r in res] == ["scapo", "scapo-no-shape_var"]
    assert _same(res[:1], results[1:])  # the full model is Table 1's SCAPO cell
    run = work / "laptop_i10_v2_s0" / "run_scapo-no-shape_var_test+no-shape_var_s0"
    assert json.loads((run / "run.json").read_text())["preset"]["losses"]["disabled"] == ["shape_var"]
    md = (out / "table3_ablation_sphere.md").read_text()
    assert "| Full |" in md and "| w/o L_shape-var |" in md and "w/o L_joint-prox (paper)" in md


def test_cells_and_their_errors():
    cells = table1_cells(["icp", "scapo"], ["oven", "safe"], "cpu", [0, 1, 2], {"safe": [0]}, refine_rows=False)
    assert [c.key for c in cells] == ["icp", "scapo_cpu_s0", "scapo_cpu_s1", "scapo_cpu_s2", "icp", "scapo_cpu_s0"]
    assert [c.category for c in cells] == ["oven"] * 4 + ["safe"] * 2
    with_refine = table1_cells(["icp", "scapo"], ["safe"], "cpu", [0])
    assert [c.key for c in with_refine] == ["icp", "scapo_cpu_s0", "scapo+refine_cpu_s0"]
    t3 = table3_cells(["oven"], "cpu", [0])
    assert [c.label for c in t3] == ["scapo", "scapo-no-shape_var", "scapo-no-dir_align", "scapo-no-joint_prox",
                                     "scapo-no-joint_boundary"]
    assert t3[1].preset == "cpu/no-shape_var" and t3[1].key == "scapo-no-shape_var_cpu+no-shape_var_s0"
    parts = table1_cells(["icp", "scapo"], ["oven"], "cpu", [0, 1], refine_rows=False, parts=["scapo/principal"])
    assert [(c.label, c.preset) for c in parts[3:]] == [("scapo-principal", "cpu/principal")] * 2
    for bad, msg in (("scapo", "METHOD/PART"), ("icp/principal", "not trained"), ("npcs/principal", "not among"),
                     ("scapo/nope", "nope")):
        with pytest.raises((ConfigError, UnknownNameError), match=msg):
            table1_cells(["icp", "scapo"], ["laptop"], "cpu", [0], parts=[bad])
    rows = table1_cells(["icp", "scapo"], ["oven"], "cpu", [0, 1], refine_rows=False,
                        option_rows=["scapo:base-frame:base_frame=principal"])
    assert [(c.label, c.run_key, dict(c.options)) for c in rows[3:]] == [
        ("scapo-base-frame", f"scapo_cpu_s{s}", {"base_frame": "principal", "refine_steps": 0}) for s in (0, 1)]
    for bad, msg in (("scapo:x", "METHOD:LABEL"), ("icp:x:a=1", "not trained"), ("npcs:x:a=1", "not among"),
                     ("scapo:x:nope=1", "unknown option")):
        with pytest.raises(ConfigError, match=msg):
            table1_cells(["icp", "scapo"], ["laptop"], "cpu", [0], option_rows=[bad])
    assert parse_category_seeds(["safe=0", "laptop=0,1,2"]) == {"safe": [0], "laptop": [0, 1, 2]}
    for bad in ("safe", "safe=", "=0", "safe=a", "safe=-1"):
        with pytest.raises(ConfigError, match="CATEGORY=SEED"):
            parse_category_seeds([bad])
    with pytest.raises(ConfigError, match="not among the categories"):
        table1_cells(["icp"], ["laptop"], "cpu", [0], {"oven": [0]})
    with pytest.raises(ConfigError, match="has no preset 'huge'"):
        table1_cells(["scapo"], ["laptop"], "huge", [0])
    with pytest.raises(UnknownNameError, match="not 'no-TERM'"):
        table3_cells(["laptop"], "cpu", [0], ablations=["colour"])
    with pytest.raises(ConfigError, match="needs both a seed and a preset"):
        Cell("scapo", "laptop", seed=0)


def test_ablation_presets():
    from scapo.models.presets import get_preset

    p = get_preset("cpu/no-shape_var/no-dir_align")
    assert p.name == "cpu/no-shape_var/no-dir_align" and p.losses.disabled == ("shape_var", "dir_align")
    assert get_preset("cpu").losses.disabled == () and get_preset("cpu/no-seg").losses.weight("seg") == 0.0
    with pytest.raises(UnknownNameError, match="unknown preset"):
        get_preset("huge/no-seg")
    with pytest.raises(UnknownNameError, match="branch_flip"):
        get_preset("cpu/no-such_thing")
    q = get_preset("cpu/no-branch_flip/no-part_init")  # our additions to the paper switch off the same way
    assert q.name == "cpu/no-branch_flip/no-part_init" and not q.branch_flip and not q.part_init
    assert q.losses.disabled == () and q.root_motion == get_preset("cpu").root_motion


def test_scapo_per_category_presets_are_labelled_rows_not_the_tables_choice():
    """``cpu-eyeglasses`` is ``cpu`` with the ladder's eyeglasses parts (chosen on val), and ``cpu-laptop`` the same
    recipe (chosen on the laptop's val split); ablations and schedules stack on them like any preset's. The tables
    train one preset per method for every category (:func:`method_preset`): a per-category preset is asked for by
    name."""
    import dataclasses

    from scapo.bench.cells import method_preset
    from scapo.models.presets import EYEGLASSES_PARTS, LAPTOP_PARTS, get_preset

    eye, parts = get_preset("cpu-eyeglasses"), get_preset("cpu/" + "/".join(EYEGLASSES_PARTS))
    assert eye.name == "cpu-eyeglasses" and eye.refine == dataclasses.replace(parts.refine, stage2_starts="D2")
    assert dataclasses.replace(parts, name=eye.name, refine=eye.refine) == eye
    assert (eye.split_init, eye.split_labels, eye.stage2_frame, eye.split_frame, eye.parts_axes, eye.axis_init,
            eye.axis_fixed, eye.losses.disabled) == ("fitted", True, "parts", "refit", "plane", "sweep", True,
                                                       ("dir_align",))
    lap = get_preset("cpu-laptop")
    recipe = get_preset("cpu/" + "/".join(LAPTOP_PARTS))
    assert lap.name == "cpu-laptop" and lap.refine == dataclasses.replace(recipe.refine, stage2_starts="O")
    assert dataclasses.replace(recipe, name=lap.name, refine=lap.refine) == lap
    # one training recipe, two names; each category's inference has its own hypothesis set of stage 2's first frame
    assert dataclasses.replace(lap, name=eye.name, refine=eye.refine) == eye
    assert method_preset("scapo", "cpu") == "cpu" and method_preset("npcs", "cpu") == "cpu"
    assert method_preset("scapo", "cpu/no-shape_var") == "cpu/no-shape_var"
    assert method_preset("scapo", "cpu-laptop") == "cpu-laptop"  # by name
    get_preset(method_preset("scapo", "cpu/sj"))
    with pytest.raises(ConfigError, match="no preset 'nope'"):
        method_preset("scapo", "nope/sj")
    six = get_preset("cpu-eyeglasses/epochs-6-5")
    assert (six.stage1_epochs, six.stage2_epochs, six.axis_init) == (6, 5, "sweep")
    cells = table1_cells(["scapo"], ["eyeglasses", "laptop", "oven"], "cpu", [0])
    assert {(c.category, c.preset) for c in cells} == {("eyeglasses", "cpu"), ("laptop", "cpu"), ("oven", "cpu")}


def test_finished_only_writes_the_done_cells_and_lists_the_missing(bench, monkeypatch, tmp_path):
    work, _, _, results = bench
    _forbid(monkeypatch, "train_method", "run_method")
    part = run_table1(["npcs", "scapo"], ["laptop"], work_dir=work, out_dir=tmp_path, seeds=[0, 1], finished_only=True,
                      **SMALL)
    assert _same(part, results)
    prov = json.loads((tmp_path / "table1_synthetic_sphere.json").read_text())["provenance"]
    assert prov["missing_cells"] == ["laptop/npcs_test_s1", "laptop/scapo_test_s1"]
    assert "**Partial table:** 2 cells" in (tmp_path / "table1_synthetic_sphere.md").read_text()
    with pytest.raises(ConfigError, match="no cell of this bench is done"):
        run_table1(["npcs"], ["laptop"], work_dir=tmp_path / "empty", out_dir=tmp_path, seeds=[0], finished_only=True,
                   **SMALL)


def test_finished_only_scores_predicted_cells_again_when_the_evaluator_changed(bench, monkeypatch, tmp_path):
    """A bench still running elsewhere: --finished-only re-evaluates the predicted cells (cheap) and never trains."""
    import scapo.bench.cells as cells

    work, _, _, results = bench
    record = work / "laptop_i10_v2_s0" / "cells" / "npcs_test_s0.scapo.json"
    saved = {p: p.read_bytes() for p in (record, record.with_suffix(".parquet"))}
    try:
        _forbid(monkeypatch, "train_method", "run_method")
        monkeypatch.setattr(cells, "evaluator_fingerprint", lambda: "changed")
        part = run_table1(["npcs"], ["laptop"], work_dir=work, out_dir=tmp_path, seeds=[0], finished_only=True,
                          **SMALL)
        assert _same(part, results[:1]) and json.loads(record.read_text())["evaluator"] == "changed"
    finally:
        for p, b in saved.items():
            p.write_bytes(b)
    data = work / "laptop_i10_v2_s0"
    with pytest.raises(ConfigError, match="npcs_test_s1 has no predictions yet"):
        cells.compute_cell(data, Cell("npcs", "laptop", seed=1, preset="test"), "scapo", evaluate_only=True)


def test_a_run_of_a_changed_preset_is_stale_set_aside_and_retrained(bench, monkeypatch, tmp_path):
    """A preset whose training fields changed after its cells were computed: the dry run says so, the
    records are no longer valid, and the old run, predictions and record are moved aside (kept)."""
    import dataclasses
    import shutil

    import scapo.bench.cells as cells
    from scapo.methods.npcs import SPEC
    from scapo.models.presets import PRESETS

    work, _, _, _ = bench
    copy = tmp_path / "work"
    shutil.copytree(work, copy)
    data = copy / "laptop_i10_v2_s0"
    monkeypatch.setitem(SPEC.presets._entries, "test", dataclasses.replace(SPEC.presets.get("test"), epochs=3))
    monkeypatch.setitem(PRESETS._entries, "test", dataclasses.replace(PRESETS.get("test"), branch_flip=True))
    plan = run_table1(["npcs", "scapo"], ["laptop"], work_dir=copy, out_dir=None, seeds=[0], dry_run=True, **SMALL)
    assert {r["key"]: r["status"] for r in plan} == {"npcs_test_s0": "retrain (stale)", "scapo_test_s0": "retrain (stale)"}
    cell = Cell("npcs", "laptop", seed=0, preset="test")
    paths = cells.cell_paths(data, cell, "scapo")
    assert cells._read_record(paths, json.loads(paths.record.read_text())["dataset_hash"]) is None
    moved = cells.set_aside_stale(paths, cell)
    assert moved is not None and moved.parent == data / "stale"
    assert {p.name for p in moved.iterdir()} == {"run_npcs_test_s0", "predictions_npcs_test_s0.npz",
                                                 "npcs_test_s0.scapo.json", "npcs_test_s0.scapo.parquet"}
    assert not paths.run.exists() and not paths.predictions.exists() and not paths.record.exists()
    monkeypatch.undo()  # the registered presets again: the untouched SCAPO cell is done, as before
    plan = run_table1(["npcs", "scapo"], ["laptop"], work_dir=copy, out_dir=None, seeds=[0], dry_run=True, **SMALL)
    assert {r["key"]: r["status"] for r in plan} == {"npcs_test_s0": "todo", "scapo_test_s0": "done"}


def test_table2_real_style_with_semi_supervised_rows(tmp_path, monkeypatch):
    """Table 2: realistic-sensor datasets, the SJ rows beside the self-supervised ones, the paper's rows beside
    ours, AP columns; a rerun recomputes nothing."""
    from scapo.bench import run_table2

    work, out = tmp_path / "work", tmp_path / "results"
    kw = dict(work_dir=work, out_dir=out, seeds=[0], **SMALL_T2)
    plan = run_table2(["icp", "op-align"], ["laptop"], dry_run=True, **kw)
    assert [r["key"] for r in plan] == ["icp", "op-align_test_s0", "op-align-sj_test+sj_s0"]
    results = run_table2(["icp", "op-align"], ["laptop"], **kw)
    assert [r.method for r in results] == ["icp", "op-align", "op-align-sj"]
    assert results[2].info["supervision"] == {"pose": False, "segmentation": True, "joint": True}
    import pandas as pd

    log = pd.read_csv(next((work / "laptop_i10_v2_s0").glob("run_op-align-sj_*")) / "log.csv")
    assert log[["sup_seg", "sup_joint"]].notna().all().all()  # trained with the labels
    cfg = json.loads((work / "laptop_i10_v2_s0" / "config.json").read_text())
    assert cfg["render"]["sensor"]["kind"] == "realistic" and cfg["render"]["cropped"] == "reject"
    md = (out / "table2_real_style.md").read_text()
    assert "| Laptop | OP-Align-style (SJ) |  | x | x |" in md and "| Laptop | OP-Align(SJ) (paper) |" in md
    assert "Protocol: op-align" in md and "(background points, label -1, left out" in md
    assert "(every joint, prismatic ones included)" in md and "Basket (symmetric" not in md  # no basket here
    # strict and symmetry-aware rotation errors side by side (the AP layout has no rotation column)
    assert "## Medians and rates" in md and "| R (deg) | R med (deg) |" in md and "R sym (deg)" in md
    assert "## Differences the training seeds and test instances support" in md
    for r in results:
        assert {"seg_75", "ap_joint_5", "ap_part_15", "min_ap_part_5"} <= set(r.summary)
    before = {s: (out / f"table2_real_style.{s}").read_text() for s in ("csv", "md", "tex")}
    _forbid(monkeypatch, "train_method", "run_method", "evaluate")
    run_table2(["icp", "op-align"], ["laptop"], **kw)
    assert {s: (out / f"table2_real_style.{s}").read_text() for s in ("csv", "md", "tex")} == before


def test_cells_computed_at_a_dirty_commit_are_listed_and_recomputed_on_request(bench, monkeypatch, tmp_path, capsys):
    """A record naming a -dirty commit (uncommitted code): the dry run flags it; --recompute-dirty moves its
    files aside (kept) and computes the cell again; a cell only evaluated from uncommitted code (trained and
    predicted at a clean commit) is evaluated again, its predictions and their commit kept."""
    import shutil

    import scapo.bench.cells as cells
    from scapo import provenance

    work, _, _, _ = bench
    copy = tmp_path / "work"
    shutil.copytree(work, copy)
    data = copy / "laptop_i10_v2_s0"
    for key, computed, evaluated in (("npcs", "0123456789abcdef-dirty", "0123456789abcdef-dirty"),
                                     ("scapo", "0123456789abcdef", "abcdef0123456789-dirty")):
        p = cells.cell_paths(data, Cell(key, "laptop", seed=0, preset="test"), "scapo").record
        rec = json.loads(p.read_text())
        rec["computed_commit"], rec["provenance"]["commit"] = computed, evaluated  # whatever this checkout is
        p.write_text(json.dumps(rec))
    paths = cells.cell_paths(data, Cell("npcs", "laptop", seed=0, preset="test"), "scapo")
    sc_paths = cells.cell_paths(data, Cell("scapo", "laptop", seed=0, preset="test"), "scapo")
    sc_sha = json.loads(sc_paths.record.read_text())["predictions_sha256"]
    methods = ["npcs", "scapo"]
    plan = run_table1(methods, ["laptop"], work_dir=copy, out_dir=None, seeds=[0], dry_run=True, **SMALL)
    assert {r["key"]: r["status"] for r in plan} == {"npcs_test_s0": "done", "scapo_test_s0": "done"}
    listing = capsys.readouterr().out
    assert "(computed at 0123456789ab-dirty; --recompute-dirty computes it again" in listing
    assert "(evaluated at abcdef012345-dirty; --recompute-dirty evaluates its predictions again" in listing
    plan = run_table1(methods, ["laptop"], work_dir=copy, out_dir=None, seeds=[0], dry_run=True,
                      recompute_dirty=True, **SMALL)
    assert {r["key"]: r["status"] for r in plan} == {"npcs_test_s0": "recompute (dirty)",
                                                      "scapo_test_s0": "re-evaluate (dirty)"}
    # recomputed as at a clean commit
    monkeypatch.setattr(cells, "provenance", lambda **kw: {**provenance.provenance(**kw), "commit": "fedcba9876543210"})
    with pytest.raises(ConfigError, match="use one of them"):
        run_table1(["npcs"], ["laptop"], work_dir=copy, out_dir=None, seeds=[0], finished_only=True,
                   recompute_dirty=True, **SMALL)
    trained, predicted = [], []
    real_train, real_run = cells.train_method, cells.run_method
    monkeypatch.setattr(cells, "train_method", lambda m, *a, **k: trained.append(m) or real_train(m, *a, **k))
    monkeypatch.setattr(cells, "run_method", lambda m, *a, **k: predicted.append(m) or real_run(m, *a, **k))
    run_table1(methods, ["laptop"], work_dir=copy, out_dir=None, seeds=[0], recompute_dirty=True, **SMALL)
    assert trained == ["npcs"] and predicted == ["npcs"]  # only the dirty cell, from scratch
    sc = json.loads(sc_paths.record.read_text())  # only scored again: its predictions and their commit kept
    assert sc["predictions_sha256"] == sc_sha and sc["computed_commit"] == "0123456789abcdef"
    assert sc["provenance"]["commit"] == "fedcba9876543210"
    moved = list((data / "dirty").iterdir())
    assert len(moved) == 1 and {p.name for p in moved[0].iterdir()} >= {"run_npcs_test_s0", "npcs_test_s0.scapo.json"}
    rec = json.loads(paths.record.read_text())
    assert rec["provenance"]["commit"] == rec["computed_commit"] == "fedcba9876543210"  # nothing kept from before
    plan = run_table1(methods, ["laptop"], work_dir=copy, out_dir=None, seeds=[0], dry_run=True,
                      recompute_dirty=True, **SMALL)
    assert {r["key"]: r["status"] for r in plan} == {"npcs_test_s0": "done", "scapo_test_s0": "done"}


def test_table2_per_category_render_settings_leave_the_other_datasets_alone():
    """Table 2's exception for basket (thin handles: a lower visibility threshold) changes basket's config only;
    every other category keeps the config hash of the datasets made before the exception existed."""
    from scapo.bench.experiments import REAL_STYLE_CATEGORY_DATA, REAL_STYLE_DATA, data_settings
    from scapo.data.config import make_config

    assert data_settings("basket", REAL_STYLE_DATA, REAL_STYLE_CATEGORY_DATA)["min_part_fraction"] == 0.03
    for cat in ("drawer", "laptop", "scissors", "suitcase"):
        kw = data_settings(cat, REAL_STYLE_DATA, REAL_STYLE_CATEGORY_DATA)
        assert kw == REAL_STYLE_DATA
        assert make_config(cat, 80, 16, 1, **kw).to_json() == make_config(cat, 80, 16, 1, **REAL_STYLE_DATA).to_json()
    assert data_settings("laptop")["random_rotation"]  # the whole sphere's settings, the default of data_settings


def test_bench_datasets_have_30_test_instances_and_table1_views_are_the_papers():
    """Issue 29's bench data at the defaults: 150 instances, a fifth of them test (30) and a tenth val; Table 1's
    views the paper's (EAP's Euler ranges, many views per training instance), its whole-sphere variant under a uniform
    SO(3) rotation in every view with the config of the datasets made before the paper's views existed, Table 2
    upright as real scans."""
    from scapo.bench.experiments import PAPER_TRAIN_VIEWS, REAL_STYLE_DATA, VIEWPOINT_DATA, BenchOptions, data_settings
    from scapo.data.config import make_config
    from scapo.data.generate import split_instances

    opts = BenchOptions()
    assert VIEWPOINT_DATA["sphere"] == {"random_rotation": True, "test_fraction": 0.2, "val_fraction": 0.1}
    for kw, vp in ((VIEWPOINT_DATA["paper"], "paper"), (VIEWPOINT_DATA["sphere"], "sphere"),
                   (data_settings("laptop", REAL_STYLE_DATA), "upright")):
        cfg = make_config("laptop", opts.instances, opts.views, 1, **kw)
        splits = split_instances(cfg.instances, cfg.test_fraction, cfg.seed, cfg.val_fraction)
        assert len(splits.test) == 30 and len(splits.val) == 15
        assert cfg.view_config.viewpoints == vp
        assert cfg.views_train == (PAPER_TRAIN_VIEWS if vp == "paper" else opts.views)
        assert ("train_views" in cfg.to_dict()) is (vp == "paper")


def test_table1_defaults_to_the_papers_viewpoints_labelled_and_named_apart(tmp_path):
    """``scapo bench table1`` without --viewpoints renders the paper's views (datasets ``..._t<train>_s<seed>_paper``,
    their card says so, training instances with their own number of views) and says so in the table's title and
    provenance; the whole sphere is labelled as harder than the paper."""
    from scapo.bench.experiments import dataset_dir

    work, out = tmp_path / "work", tmp_path / "out"
    kw = {**SMALL_T2, "instances": 6, "train_views": 3}
    plan = run_table1(["icp"], ["laptop"], work_dir=work, out_dir=out, seeds=[0], dry_run=True, **kw)
    assert [r["key"] for r in plan] == ["icp"]
    run_table1(["icp"], ["laptop"], work_dir=work, out_dir=out, seeds=[0], **kw)
    data = work / "laptop_i6_v2_t3_s0_paper"
    assert dataset_dir(work, "laptop", 6, 2, 0, {"viewpoints": "paper", "train_views": 3}) == data
    card = json.loads((data / "card.json").read_text())
    assert card["viewpoints"] == "paper" and card["views_per_instance"] == {"train": 3, "val": 2, "test": 2}
    assert card["splits"]["train"]["samples"] == 3 * len(card["splits"]["train"]["instances"])
    assert card["config"]["view"]["object_euler_deg"] == [[-22.5, 22.5]] * 3
    prov = json.loads((out / "table1_synthetic.json").read_text())["provenance"]
    assert prov["data"]["viewpoints"] == "paper" and prov["data"]["train_views"] == 3
    md = (out / "table1_synthetic.md").read_text()
    assert "the paper's viewpoints" in md.splitlines()[0] and "Chance:" not in md
    from scapo.eval.tables import viewpoints_title

    assert "harder than the paper" in viewpoints_title({"data": {"random_rotation": True}})
    with pytest.raises(ConfigError, match="contradicts"):
        run_table1(["icp"], ["laptop"], work_dir=work, out_dir=out, dry_run=True, upright=True, **SMALL)
    with pytest.raises(ConfigError, match="train-views must be >= 1"):
        run_table1(["icp"], ["laptop"], work_dir=work, out_dir=out, dry_run=True, **{**kw, "train_views": 0})


def test_table1_in_the_parts_alone_regime_is_named_and_labelled_apart(tmp_path):
    """``--parts-alone`` (EAP's data regime) renders datasets of their own (``..._paper_parts``, the card records it),
    writes ``table1_synthetic_parts_alone`` and says so in the title and provenance; Table 2 refuses it."""
    from scapo.bench.experiments import dataset_dir, run_table
    from scapo.eval.tables import viewpoints_title

    work, out = tmp_path / "work", tmp_path / "out"
    kw = {**SMALL_T2, "instances": 6, "train_views": 3}
    run_table1(["icp"], ["laptop"], work_dir=work, out_dir=out, seeds=[0], parts_alone=True, **kw)
    data = work / "laptop_i6_v2_t3_s0_paper_parts"
    assert dataset_dir(work, "laptop", 6, 2, 0, {"viewpoints": "paper", "train_views": 3, "parts_alone": True}) == data
    card = json.loads((data / "card.json").read_text())
    assert card["parts_alone"] is True and card["viewpoints"] == "paper"
    table = json.loads((out / "table1_synthetic_parts_alone.json").read_text())
    assert table["provenance"]["data"]["parts_alone"] is True
    assert "every part rendered alone" in (out / "table1_synthetic_parts_alone.md").read_text().splitlines()[0]
    assert "rendered alone" not in viewpoints_title({"data": {"viewpoints": "paper"}})
    with pytest.raises(ConfigError, match="--parts-alone are for Tables 1 and 3"):
        run_table("table2", ["icp"], ["laptop"], work_dir=work, out_dir=out, dry_run=True, parts_alone=True)


def test_upright_diagnostic_renders_upright_data_in_its_own_folder_and_says_so(bench, tmp_path):
    """``--upright`` changes only the rotation: the same cells, datasets in WORK/upright/ whose config has no
    object rotation (the rest of the config equal to Table 1's), a table named ``*_upright`` whose provenance and
    title say so; Table 2 (upright: real scans are natural views) refuses other viewpoints, and Table 1's provenance
    records its rotation."""
    from scapo.bench import run_table2
    from scapo.bench.experiments import data_settings
    from scapo.data.config import make_config

    work, out, _, _ = bench
    assert json.loads((out / "table1_synthetic_sphere.json").read_text())["provenance"]["data"]["random_rotation"] is True
    up_work, up_out = tmp_path / "work", tmp_path / "out"
    plan = run_table1(["icp"], ["laptop"], work_dir=up_work, out_dir=up_out, seeds=[0], dry_run=True, upright=True,
                      **SMALL_T2)
    assert [r["key"] for r in plan] == ["icp"] and not up_work.exists()
    run_table1(["icp"], ["laptop"], work_dir=up_work, out_dir=up_out, seeds=[0], upright=True, **SMALL_T2)
    card = json.loads((up_work / "upright" / "laptop_i10_v2_s0" / "card.json").read_text())
    assert card["config"]["view"]["random_rotation"] is False and card["viewpoints"] == "upright"
    rotated = json.loads(make_config("laptop", 10, 2, 0, **data_settings("laptop")).to_json())
    upright = dict(card["config"])
    assert {**upright, "view": {**upright["view"], "random_rotation": True}} == rotated
    assert not (up_work / "laptop_i10_v2_s0").exists()  # never beside the rotated datasets
    table = json.loads((up_out / "table1_synthetic_upright.json").read_text())
    assert table["provenance"]["data"]["random_rotation"] is False
    md = (up_out / "table1_synthetic_upright.md").read_text()
    assert "objects upright" in md.splitlines()[0] and "Chance:" not in md  # no uniform ground truth, no chance level
    sphere = (out / "table1_synthetic_sphere.md").read_text()
    assert "R 126.5 deg on average" in sphere and "whole sphere" in sphere.splitlines()[0]
    with pytest.raises(ConfigError, match="views are upright"):
        run_table2(["icp"], ["laptop"], work_dir=up_work, out_dir=up_out, dry_run=True, viewpoints="paper", **SMALL_T2)


def test_the_bench_refuses_a_dirty_checkout_and_a_table_of_mixed_commits_unless_told(bench, tmp_path, monkeypatch):
    """Every cell of a table at one clean commit (issue 29): computing from uncommitted code is refused, and so is
    writing a table whose cells come from several commits or from a dirty one; the message names the cells."""
    import shutil

    import scapo.bench.cells as cells
    import scapo.bench.experiments as experiments
    from scapo.bench.experiments import check_commits

    work, _, _, _ = bench
    monkeypatch.setattr(experiments, "git_commit", lambda: "0123456789abcdef-dirty")
    small = {**SMALL, "allow_dirty": False}
    with pytest.raises(ConfigError, match="uncommitted changes.*--allow-dirty"):
        run_table1(["npcs"], ["laptop"], work_dir=work, out_dir=tmp_path, seeds=[0], **small)
    monkeypatch.setattr(experiments, "git_commit", lambda: "0123456789abcdef")
    copy = tmp_path / "work"
    shutil.copytree(work, copy)
    data = copy / "laptop_i10_v2_s0"
    for key, sha in (("npcs", "aaaaaaaaaaaaaaaa"), ("scapo", "bbbbbbbbbbbbbbbb")):
        p = cells.cell_paths(data, Cell(key, "laptop", seed=0, preset="test"), "scapo").record
        rec = json.loads(p.read_text())
        rec["computed_commit"], rec["provenance"]["commit"] = sha, sha
        p.write_text(json.dumps(rec))
    with pytest.raises(ConfigError, match=r"computed at 2 commits \(aaaaaaaaaaaaaaaa: npcs_test_s0/laptop; "
                                          r"bbbbbbbbbbbbbbbb: scapo_test_s0/laptop\).*--allow-mixed-commits"):
        run_table1(["npcs", "scapo"], ["laptop"], work_dir=copy, out_dir=tmp_path / "t", seeds=[0], **small)
    assert not (tmp_path / "t" / "table1_synthetic_sphere.md").exists()
    run_table1(["npcs", "scapo"], ["laptop"], work_dir=copy, out_dir=tmp_path / "t", seeds=[0],
               **{**small, "allow_mixed_commits": True})
    assert (tmp_path / "t" / "table1_synthetic_sphere.md").exists()
    recs = [{"provenance": {"commit": "cccccccccccccccc-dirty"}}]
    with pytest.raises(ConfigError, match="uncommitted code"):
        check_commits([Cell("npcs", "laptop", seed=0, preset="test")], recs)
    assert check_commits([Cell("npcs", "laptop", seed=0, preset="test")], recs, allow_dirty=True)
    # trained cells charged in core-seconds of two kinds of CPU: the budget bought other steps on each
    two = [Cell("npcs", "laptop", seed=s, preset="test") for s in (0, 1)]
    charged = [{"provenance": {"commit": "c" * 16, "cpu_kind": k}, "ledger": {"unit": "core-seconds"}}
               for k in ("CPU A, family 1 model 2", "CPU B, family 3 model 4")]
    with pytest.raises(ConfigError, match=r"charged on 2 kinds of CPU \(CPU A, family 1 model 2: npcs_test_s0/laptop; "
                                          r"CPU B, family 3 model 4: npcs_test_s1/laptop\)"):
        check_commits(two, charged)
    assert check_commits(two, charged, allow_mixed_commits=True)
    assert check_commits(two, [{**r, "ledger": None} for r in charged])  # before the ledger: nothing charged


def test_table1_rows_are_one_pass_and_the_refined_prediction_is_a_row_of_its_own(bench, tmp_path):
    """Equal treatment (issue 29): SCAPO's Table 1 row predicts without its test-time refinement, as every other
    method does; "SCAPO (ours) + refine" is a separate row predicted from the same trained run (trained once) by
    the method-independent refinement (scapo.steps.refine) that every refinable method gets; Table 3's rows
    are one-pass too."""
    import shutil

    from scapo.bench.cells import cell_paths
    from scapo.eval import Predictions

    cells = table1_cells(["icp", "scapo"], ["laptop"], "test", [0])
    by = {c.label: c for c in cells}
    assert set(by) == {"icp", "scapo", "scapo+refine"}
    assert by["scapo"].options == (("refine_steps", 0),)
    assert by["scapo+refine"].options == (("refine", True), ("refine_steps", 0))
    assert by["scapo+refine"].run_key == by["scapo"].key
    assert all(c.options == (("refine_steps", 0),) for c in table3_cells(["laptop"], "test", [0]))
    work, _, _, _ = bench
    copy = tmp_path / "work"
    shutil.copytree(work, copy)
    res = run_table1(["scapo"], ["laptop"], work_dir=copy, out_dir=tmp_path / "t", seeds=[0],
                     **{**SMALL, "refine_rows": True})
    assert sorted(r.method for r in res) == ["scapo", "scapo+refine"]
    data = copy / "laptop_i10_v2_s0"
    one, refined = (Predictions.load(cell_paths(data, by[k], "scapo").predictions) for k in ("scapo", "scapo+refine"))
    # one run (the one-pass row's predictions were made in the fixture's folder, this copy's origin)
    assert Path(one.info["run"]).name == Path(refined.info["run"]).name == "run_scapo_test_s0"
    assert not list(data.glob("run_scapo+refine*"))
    from scapo.methods.scapo import inference_settings
    from scapo.models.presets import get_preset

    run = data / "run_scapo_test_s0"
    assert one.info["inference"] == inference_settings(run, {"refine_steps": 0}) and one.info["inference"]["steps"] == 0
    # SCAPO's own refinement is off in both rows; the refined row took the method-independent step
    assert refined.info["inference"] == inference_settings(run, {"refine": True}) == one.info["inference"]
    assert refined.info["refine"]["steps"] > 0 and "refine" not in one.info
    assert get_preset("test").refine.steps == 0
    assert "SCAPO (ours) + refine" in (tmp_path / "t" / "table1_synthetic_sphere.md").read_text()


def test_the_gpu_script_runs_on_cpu_with_the_test_presets(tmp_path):
    """``bench/gpu.sh`` (issue 30) with ``DEVICE=cpu PRESET=test`` on a tiny dataset: it trains, predicts and
    evaluates through ``scapo bench table1`` and writes the table with provenance (a rerun resumes as every
    ``scapo bench`` does: test_rerun_recomputes_nothing_and_rewrites_identical_tables); without CUDA the GPU run
    refuses with a scapo: message."""
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parent.parent
    scapo_bin = Path(sys.executable).parent / "scapo"
    env = {**os.environ, "DEVICE": "cpu", "PRESET": "test", "INSTANCES": "10", "VIEWS": "2", "METHODS": "npcs",
           "WORK": str(tmp_path / "work"), "OUT": str(tmp_path / "out"), "SCAPO": str(scapo_bin)}
    # 2 views per training instance instead of the paper regime's 64: the renders are not what is tested here
    run = subprocess.run(["bash", str(root / "bench" / "gpu.sh"), "--allow-dirty", "--train-views", "2"], env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    table = json.loads((tmp_path / "out" / "table1_gpu_test_laptop.json").read_text())
    cells = table["provenance"]["cells"]
    # one trained method (ICP's cells, untouched by PRESET and DEVICE, are tested through bench table1 above)
    assert {c["cell"] for c in cells} == {"npcs_test_s0"} and table["provenance"]["preset"] == "test"
    assert all(c["device"].startswith("cpu") for c in cells)
    import torch

    if not torch.cuda.is_available():
        gpu = subprocess.run(["bash", str(root / "bench" / "gpu.sh")], env={**env, "DEVICE": "cuda"},
                             capture_output=True, text=True, timeout=60)
        assert gpu.returncode == 2 and "scapo: bench/gpu.sh: no CUDA device" in gpu.stderr


def test_cells_of_an_unpinned_dataset_are_adopted_by_its_regeneration_only_when_they_show_it_is_theirs(
        bench, monkeypatch, tmp_path):
    """Issue 31's cells archived before datasets were pinned name a dataset that only a machine of their CPU kind
    generates. ``adopt_dataset`` re-labels them with another kind's regeneration when every archived prediction
    scores the same on it and ICP computed again on its inputs gives the archived predictions; a regeneration whose
    inputs (one float32 ulp) or ground truth (1e-6) differ adopts nothing and leaves every archived byte as it was."""
    import shutil

    import numpy as np

    from scapo.bench.archive import ADOPTED, adopt_dataset, archive_conflict
    from scapo.data import load

    work, _, _, results = bench
    data = tmp_path / "work" / "laptop_i10_v2_s0"
    shutil.copytree(work / data.name, data)
    legacy = tmp_path / "legacy"
    run_table1(["icp", "npcs", "scapo"], ["laptop"], work_dir=data.parent, out_dir=None, seeds=[0], archive=legacy,
               archive_predictions=True, **SMALL)  # adoption scores the archived predictions again
    shutil.rmtree(legacy / data.name / "dataset")  # archived before datasets were pinned
    old = load(data, "test").dataset_hash

    def snapshot() -> dict:
        return {p: p.read_bytes() for p in sorted((legacy / data.name).rglob("*")) if p.is_file()}

    before = snapshot()
    for field, change, why in (("points", lambda a: np.nextafter(a, np.float32(9)), "nothing shows that its inputs"),
                               ("joint_state", lambda a: a + 1e-6, "differs from its archived scores")):
        other = tmp_path / field / data.name
        _generated_elsewhere(data, other, field, change)
        rep = adopt_dataset(other, legacy)
        assert rep["status"] == "different" and why in rep["why"], rep
        if field == "points":  # ICP's report says where its predictions moved
            assert rep["untrained"][0]["fields"]["part_pose"]["samples_over_atol"] > 0
        assert snapshot() == before
    fresh = tmp_path / "fresh" / data.name  # another CPU: a camera pose's last bit
    _generated_elsewhere(data, fresh, "T_cam_obj", lambda a: np.nextafter(a, 2 * a + 1))
    new = load(fresh, "test").dataset_hash
    assert new != old and "which is not pinned" in archive_conflict(fresh, legacy)
    rep = adopt_dataset(fresh, legacy)
    assert rep["status"] == "adopted", rep.get("why")
    assert rep["from"] == old and rep["dataset_hash"] == new and rep["cells"] == 3
    assert 0 <= rep["max_abs_diff"] < 1e-9 and [u["method"] for u in rep["untrained"]] == ["icp"]
    assert rep["untrained"][0]["within_atol"]
    evidence = json.loads((legacy / data.name / "dataset" / ADOPTED).read_text())
    assert {c["cell"] for c in evidence["cell_evidence"]} == {"icp", "npcs_test_s0", "scapo_test_s0"}
    assert json.loads((legacy / data.name / "dataset" / "card.json").read_text())["dataset_hash"] == new
    assert archive_conflict(fresh, legacy) == "" and adopt_dataset(fresh, legacy)["status"] == "pinned"
    for rec_path in (legacy / data.name / "cells").glob("*.json"):
        rec = json.loads(rec_path.read_text())
        assert rec.pop("adopted")["from"] == old and rec["dataset_hash"] == new and old not in json.dumps(rec)
    # the bench restores the adopted cells on the regenerated dataset and computes nothing
    _forbid(monkeypatch, "train_method", "run_method", "evaluate")
    again = run_table1(["npcs", "scapo"], ["laptop"], work_dir=fresh.parent, out_dir=tmp_path / "out", seeds=[0],
                       archive=legacy, **SMALL)
    table = json.loads((tmp_path / "out" / "table1_synthetic_sphere.json").read_text())["provenance"]
    assert table["datasets"]["laptop"] == new[:16] and table["commits"] == sorted({c["commit"] for c in table["cells"]})
    assert [c["adopted_from"] for c in table["cells"]] == [old[:16]] * 2
    assert f"(dataset {old[:12]}, adopted)" in (tmp_path / "out" / "table1_synthetic_sphere.md").read_text()
    for a, b in zip(again, results):
        assert a.summary.keys() == b.summary.keys()
        for k, v in a.summary.items():
            assert v == pytest.approx(b.summary[k], abs=1e-9, nan_ok=True), k


def _digest_table(cells: list[tuple[str, str, int, float]], hashes: dict[str, str]) -> dict:
    """A minimal bench table JSON: (method, category, seed, S) per cell, a one-metric bootstrap a vs b."""
    return {
        "provenance": {"commits": ["c0"], "devices": ["cpu"], "compute_hours": 1.0, "training_seeds": {},
                       "datasets": hashes,
                       "cells": [{"category": c, "cell": f"{m}_s{s}", "train_s": 3600.0, "predict_s": 0.0,
                                  "evaluate_s": 0.0} for m, c, s, _ in cells]},
        "results": [{"method": m, "category": c, "seed": s, "summary": {"S": v}} for m, c, s, v in cells],
        "pairwise_bootstrap": {"draws": 10, "level": 0.95, "metrics": {"S": [
            {"a": "a", "b": "b", "a_value": 22.5, "b_value": 40.0, "diff": -17.5, "interval": [-20.0, -15.0],
             "supported": True, "better": "b"}]}},
        "self_supervised_ordering": {"categories": ["x", "y"], "metrics": {"S": {
            "values": {"a": 22.5, "b": 40.0}, "best": "b", "against": {"a": {"seeds_separate": True}}}}},
    }


def test_compute_counts_each_training_once():
    """A "+ refine" cell predicts from its one-pass cell's run, whose training its record repeats: the table's
    compute adds only its prediction; an untrained cell (ICP) adds its prediction; records without ``run`` fall
    back to the one-pass cell's run; cells of two tables on one dataset count once with a shared ``seen``."""
    from scapo.bench.experiments import compute_seconds, training_run

    cells = [{"category": "laptop", "cell": "eap_cpu_s0", "run": "run_eap_cpu_s0", "train_s": 600.0,
              "predict_s": 60.0, "evaluate_s": 1.0},
             {"category": "laptop", "cell": "eap+refine_cpu_s0", "run": "run_eap_cpu_s0", "train_s": 600.0,
              "predict_s": 120.0, "evaluate_s": 1.0},
             {"category": "laptop", "cell": "scapo-sj_cpu+sj_s2", "train_s": 900.0, "predict_s": 30.0},
             {"category": "laptop", "cell": "scapo-sj+refine_cpu+sj_s2", "train_s": 900.0, "predict_s": 90.0},
             {"category": "laptop", "cell": "icp", "predict_s": 200.0, "evaluate_s": 0.5}]
    assert training_run(cells[3]) == "run_scapo-sj_cpu+sj_s2"
    assert compute_seconds(cells) == 600 + 61 + 121 + 900 + 30 + 90 + 200.5
    seen: set = set()
    first = compute_seconds(cells, {"laptop": "h1"}, seen)
    assert first == compute_seconds(cells) and compute_seconds(cells[:2], {"laptop": "h1"}, seen) == 0.0
    assert compute_seconds(cells[:1], {"laptop": "h2"}, seen) == 661.0  # another dataset: another run


def test_table_digest_reads_the_tables_numbers(tmp_path):
    """``bench/diagnostics/table_digest.py`` (the numbers of issue 31's status paragraphs): the Mean row is the mean over
    categories of the per-category means over seeds, a pair's interval is signed as asked, a cell two tables share
    (same dataset hash and key) counts once in the compute, and bad input ends with a ``scapo:`` message."""
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / "table_digest.py"
    t1 = _digest_table([("a", "x", 0, 10.0), ("a", "x", 1, 20.0), ("a", "y", 0, 30.0), ("b", "x", 0, 40.0),
                        ("b", "y", 0, 40.0)], {"x": "h1", "y": "h2"})
    # a_s0 on x is t1's cell; a+refine_s0 predicts from a_s0's run: its training (repeated in its record) is not new
    t3 = _digest_table([("a", "x", 0, 10.0), ("c", "x", 0, 5.0), ("a+refine", "x", 0, 11.0)], {"x": "h1"})
    for name, t in (("t1.json", t1), ("t3.json", t3)):
        (tmp_path / name).write_text(json.dumps(t))
    run = subprocess.run([sys.executable, str(script), str(tmp_path / "t1.json"), str(tmp_path / "t3.json"),
                          "--pair", "b,a", "--mean", "S"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    out = run.stdout
    assert "mean over categories of S: a 22.50, b 40.00" in out  # a: mean(15, 30); b: mean(40, 40)
    assert "mean S: best b 40; a 22.5 (diff +17.5 [+15, +20], seeds separate)" in out
    assert "b minus a:\n  mean S: +17.5 [+15, +20]\n" in out
    assert "## together: 7 distinct cells, 6.0 core-hours" in out  # 5 + 3 cells, one shared; 6 trainings
    (tmp_path / "bad.json").write_text(json.dumps({"results": []}))
    (tmp_path / "nan.json").write_text("NaN")
    (tmp_path / "empty.json").write_text(json.dumps({**t1, "results": []}))
    (tmp_path / "shape.json").write_text(json.dumps({**t1, "results": [1, 2]}))
    for args in (["missing.json"], [str(tmp_path / "bad.json")], [str(tmp_path / "t1.json"), "--pair", "a"],
                 [str(tmp_path / "nan.json")], [str(tmp_path / "empty.json")], [str(tmp_path / "shape.json")],
                 [str(tmp_path / "t1.json"), "--pair", "a,nosuch"], [str(tmp_path / "t1.json"), "--mean", "nosuch"]):
        bad = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, cwd=tmp_path)
        assert bad.returncode == 2 and bad.stderr.startswith("scapo: ") and "Traceback" not in bad.stderr, args


def test_regime_compare_puts_two_tables_beside_the_papers_rows(tmp_path):
    """``bench/diagnostics/regime_compare.py``: per category and method the mean over training seeds of each table's cells (with
    their spread), the paper's row beside them, the within-2x check on the first table's R sym, and ``scapo:``
    errors for a missing table or a method it does not hold."""
    import subprocess
    import sys

    script = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / "regime_compare.py"

    def table(vals, rotated):
        res = [{"method": "npcs", "category": "laptop", "seed": s, "summary": {"S": 90.0, "R": v, "R_sym": v,
                                                                                "D": 3.0, "C": 0.05}}
               for s, v in enumerate(vals)]
        return {"results": res, "provenance": {"commits": ["abcdef0123"], "data": {"random_rotation": rotated},
                                               "datasets": {"laptop": "0123456789abcdef"}}}

    (tmp_path / "p.json").write_text(json.dumps(table([10.0, 14.0, 12.0], False)))
    (tmp_path / "s.json").write_text(json.dumps(table([60.0, 70.0, 80.0], True)))
    run = subprocess.run([sys.executable, str(script), "--table", f"paper={tmp_path / 'p.json'}", "--table",
                          f"sphere={tmp_path / 's.json'}", "--methods", "npcs", "--categories", "laptop", "--paper",
                          "npcs=NPCS-EPN", "--within", "2", "--out", str(tmp_path / "cmp")],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    md = (tmp_path / "cmp.md").read_text()
    assert "| laptop | npcs | paper | 0,1,2 | 90.0 ± 0.0 | 12.0 ± 2.0 |" in md
    assert "| laptop | npcs | sphere | 0,1,2 |" in md and "| laptop | npcs | paper (NPCS-EPN) | - | - | 8.1 |" in md
    assert "npcs laptop: R sym 12.0 deg against the paper's 8.07 (1.5x): within" in md
    res = json.loads((tmp_path / "cmp.json").read_text())
    assert res["checks"][0]["within"] is True
    for args in (["--table", "x=missing.json"], ["--table", f"p={tmp_path / 'p.json'}", "--methods", "icp"]):
        bad = subprocess.run([sys.executable, str(script), *args, *([] if "--methods" in args else ["--methods", "npcs"]),
                              "--categories", "laptop"], capture_output=True, text=True, cwd=tmp_path)
        assert bad.returncode == 2 and bad.stderr.startswith("scapo: ") and "Traceback" not in bad.stderr, args


def test_the_agreement_benchmark_trains_a_method_eagerly_and_compiled_and_compares_the_losses(tmp_path, capsys):
    """``scapo bench perf --what agreement``: the method's first steps twice on one dataset and seed, eager and
    compiled; the compiled path's compilation is reported apart and its losses agree with the eager ones (float32
    kernels fused differently); without --method it is a clear error."""
    from scapo.cli.main import main

    data = Path(__file__).parent / "data" / "pin_laptop"
    assert main(["bench", "perf", "--what", "agreement", "--data", str(data), "--method", "npcs", "--preset", "test",
                 "--steps", "3", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "agreement_npcs_test_pin_laptop.json").read_text())["rows"]
    assert [r["path"] for r in rows] == ["eager", "compiled"] and all(r["steps"] == 3 for r in rows)
    assert rows[0]["compile_s"] == 0 and rows[1]["compile_s"] > 0
    assert rows[1]["rel_diff_max"] < 1e-4
    assert main(["bench", "perf", "--what", "agreement", "--data", str(data)]) == 2
    assert "needs --data DATASET and --method METHOD" in capsys.readouterr().err


def test_an_archive_of_per_cell_metrics_files_is_packed_into_one_and_each_cells_table_comes_back(tmp_path):
    """``pack_archive``: an older archive's per-cell parquet files (cells of other columns: another protocol, another
    number of parts) go into one packed file; each cell's table comes back with its own columns, order and dtypes
    (integers stay integers although another cell lacks the column); the old files are deleted; a cell the archive does
    not hold is None."""
    import numpy as np
    import pandas as pd

    from scapo.bench.archive import PACKED, archived_per_sample, pack_archive, same_as_archived

    cells = tmp_path / "archive" / "laptop_i10_v2_s0" / "cells"
    cells.mkdir(parents=True)
    a = pd.DataFrame({"instance_id": np.arange(4), "view_id": np.zeros(4, dtype=np.int64), "S": [1.5, 2.0, np.nan, 4.0],
                      "joints_matched": np.ones(4, dtype=np.int64)})
    b = pd.DataFrame({"instance_id": np.arange(3), "R_sym": [0.1, 0.2, 0.3], "view_id": np.ones(3, dtype=np.int64)})
    a.to_parquet(cells / "npcs_test_s0.scapo.parquet", index=False)
    b.to_parquet(cells / "icp.eap.parquet", index=False)
    assert archived_per_sample(cells, "icp.eap").equals(b)  # an older archive is read as it is
    assert pack_archive(tmp_path / "archive") == 2
    assert sorted(p.name for p in cells.iterdir()) == [PACKED]
    for stem, df in (("npcs_test_s0.scapo", a), ("icp.eap", b)):
        back = archived_per_sample(cells, stem)
        assert same_as_archived(back, df) and list(back.dtypes) == list(df.dtypes)
    assert archived_per_sample(cells, "scapo_test_s0.scapo") is None
    assert pack_archive(tmp_path / "archive") == 0  # nothing left to pack


def test_a_packed_archive_keeps_floats_as_float32_and_unit_columns_as_their_rule(tmp_path):
    """The packed file stores float64 metrics as float32 and a column that is another times a unit factor (``t_cm`` =
    100 ``t``) as that rule; each cell comes back with its own columns, order and dtypes, floats within float32
    rounding, NaNs where they were; a packed file of the earlier float64 layout is read as it is and repacked by
    ``pack_archive``; a column that only looks like a unit column (not 100 times its base) is stored."""
    import json

    import numpy as np
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    from scapo.bench.archive import PACKED, PRECISION, archived_per_sample, as_archived, pack_archive, same_as_archived

    rng = np.random.default_rng(0)
    t = rng.random(50)
    df = pd.DataFrame({"instance_id": np.arange(50), "t": t, "t_cm": 100 * t, "R": rng.random(50) * 180,
                       "C_j0": np.where(np.arange(50) % 7 == 0, np.nan, t), "C_cm_j0": np.nan,
                       "state_cm": rng.random(50)})
    df["C_cm_j0"] = 100 * df["C_j0"]
    cells = tmp_path / "archive" / "laptop_i10_v2_s0" / "cells"
    cells.mkdir(parents=True)
    layout = {"columns": list(df.columns), "dtypes": {c: str(d) for c, d in df.dtypes.items()}}  # earlier layout
    table = pa.Table.from_pandas(df.assign(_cell="icp.eap"), preserve_index=False)
    pq.write_table(table.replace_schema_metadata({b"scapo_cells": json.dumps({"icp.eap": layout}).encode()}),
                   cells / PACKED)
    assert archived_per_sample(cells, "icp.eap").equals(df)  # the earlier layout comes back exactly
    assert pack_archive(tmp_path / "archive") == 1
    meta = json.loads(pq.read_schema(cells / PACKED).metadata[b"scapo_cells"])["icp.eap"]
    assert meta["precision"] == PRECISION and sorted(meta["derived"]) == ["C_cm_j0", "t_cm"]
    stored = pq.read_table(cells / PACKED)
    assert "t_cm" not in stored.column_names and "state_cm" in stored.column_names
    assert stored.schema.field("R").type == pa.float32()
    back = archived_per_sample(cells, "icp.eap")
    assert same_as_archived(back, df) and not back.equals(df)  # float32 rounding, within 1e-6
    assert list(back.columns) == list(df.columns) and list(back.dtypes) == list(df.dtypes)
    assert np.array_equal(np.isnan(back["C_cm_j0"]), np.isnan(df["C_cm_j0"]))
    assert as_archived(df).equals(back)  # what a cell scored again is compared with
    assert pack_archive(tmp_path / "archive") == 0  # nothing left to pack
    off = df.copy()
    off.loc[3, "R"] += 1e-3
    assert not same_as_archived(back, off)


def test_an_option_row_the_run_would_refuse_is_refused_by_the_dry_run_too():
    """``--option-row scapo:axis:hinge_axis=true`` passed the dry run and was refused by the options' own rule
    (hinge_axis needs hinge) after training; the rules between options are checked with the cells."""
    with pytest.raises(ConfigError, match="hinge_axis=true re-estimates the axes within the hinge step; give "
                                          "hinge=true too"):
        table1_cells(["icp", "scapo"], ["laptop"], "cpu", [0], option_rows=["scapo:axis:hinge_axis=true"])
    cells = table1_cells(["icp", "scapo"], ["laptop"], "cpu", [0], option_rows=["scapo:hinge:hinge=true,hinge_axis=true"])
    assert "scapo-hinge" in [c.label for c in cells]
