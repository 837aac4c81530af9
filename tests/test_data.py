"""Datasets: field contract, split by instance, determinism, resume, corruption, config mismatch."""

import json
import shutil

import numpy as np
import pandas as pd
import pytest
import torch

from scapo.data import generate, load, make_config, plan, split_instances
from scapo.errors import ConfigError, CorruptShardError, DatasetError, UnknownNameError

SPEC_FIELDS = {
    "points": ((-1, 3), np.float32), "part_label": ((-1,), np.int64), "npcs": ((-1, 3), np.float32),
    "part_pose": ((2, 4, 4), np.float64), "joint_type": ((1,), np.int64), "joint_parts": ((1, 2), np.int64),
    "joint_axis": ((1, 3), np.float64), "joint_pivot": ((1, 3), np.float64), "joint_state": ((1,), np.float64),
    "joint_limit": ((1, 2), np.float64), "T_cam_obj": ((4, 4), np.float64), "K": ((3, 3), np.float64),
    "bbox_diag": ((), np.float64),
}
META = {"category": str, "instance_id": int, "view_id": int, "seed": int}


def test_loaded_items_have_exactly_the_spec_fields(laptop_data):
    ds = load(laptop_data, "train")
    item = ds[0]
    assert set(item) == set(SPEC_FIELDS) | set(META)
    for k, (shape, dtype) in SPEC_FIELDS.items():
        assert item[k].dtype == dtype, k
        assert item[k].shape == tuple(1024 if s == -1 else s for s in shape), k
    for k, t in META.items():
        assert isinstance(item[k], t), k
    assert item["category"] == "laptop" and item["seed"] == 3
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=4)))
    assert batch["points"].shape == (4, 1024, 3) and batch["points"].dtype == torch.float32
    assert len(ds[-1]["points"]) == 1024
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_split_is_by_instance(laptop_data):
    tr, te = load(laptop_data, "train"), load(laptop_data, "test")
    assert len(tr) == 6 * 6 and len(te) == 2 * 6
    assert not set(tr.manifest["instance_id"]) & set(te.manifest["instance_id"])
    assert len(load(laptop_data, "all")) == 48
    card = json.loads((laptop_data / "card.json").read_text())
    assert card["splits"]["test"]["instances"] == sorted(set(te.manifest["instance_id"]))
    assert split_instances(10, 0.1, 0) == split_instances(10, 0.1, 0)
    assert len(split_instances(10, 0.1, 0)[1]) == 1 and len(split_instances(2, 0.1, 0)[1]) == 1
    with pytest.raises(DatasetError, match="unknown split"):
        load(laptop_data, "validation")
    with pytest.raises(DatasetError, match="has no val split"):  # this fixture was generated with --val-fraction 0
        load(laptop_data, "val")


def test_default_generate_writes_train_val_and_test_by_instance(tmp_path):
    cfg = make_config("oven", 10, 2, seed=4, shard_size=8)
    assert cfg.val_fraction == 0.1 and cfg.test_fraction == 0.1
    generate(cfg, tmp_path / "d", progress=False)
    splits = {s: load(tmp_path / "d", s) for s in ("train", "val", "test")}
    ids = {s: set(ds.manifest["instance_id"]) for s, ds in splits.items()}
    assert [len(ids[s]) for s in ("train", "val", "test")] == [8, 1, 1]
    assert not ids["train"] & ids["val"] and not ids["train"] & ids["test"] and not ids["val"] & ids["test"]
    assert len(splits["val"]) == 2 and splits["val"][0]["instance_id"] in ids["val"]
    card = json.loads((tmp_path / "d" / "card.json").read_text())
    assert card["splits"]["val"]["instances"] == sorted(ids["val"])
    # the test instances are those of the same seed without a val split (draws are independent)
    assert split_instances(10, 0.1, 4, 0.1).test == split_instances(10, 0.1, 4).test
    assert split_instances(10, 0.1, 4).val == [] and split_instances(2, 0.5, 0, 0.1).val == []
    # a dataset written without a val split has the config (and hash) of one written before val splits existed
    old = make_config("oven", 10, 2, seed=4, shard_size=8, val_fraction=0.0).to_dict()
    assert "val_fraction" not in old
    with pytest.raises(ConfigError, match="val_fraction"):
        make_config("oven", 10, 2, test_fraction=0.5, val_fraction=0.5)


def test_methods_predict_the_val_split_and_the_evaluator_scores_it(tmp_path):
    from scapo.eval import evaluate
    from scapo.methods import METHODS, run_method

    d = tmp_path / "d"
    generate(make_config("laptop", 6, 3, seed=1, test_fraction=0.2, val_fraction=0.2), d, progress=False)
    preds = run_method("icp", d, tmp_path / "p.npz", **METHODS.get("icp").quick_options)  # the splits, not ICP
    assert set(preds.split) == {"test", "val"}
    val, test = evaluate(d, preds, split="val"), evaluate(d, preds)
    assert val.split == "val" and val.summary["samples"] == len(load(d, "val")) == 3
    assert test.split == "test" and test.summary["samples"] == len(load(d, "test")) == 3


def test_manifest_and_card(laptop_data):
    m = pd.read_parquet(laptop_data / "manifest.parquet")
    assert list(m["sample_id"]) == list(range(48))
    assert {"split", "shard", "row", "category", "instance_id", "view_id", "seed", "attempts"} <= set(m.columns)
    card = json.loads((laptop_data / "card.json").read_text())
    assert card["category"] == "laptop" and card["part_names"] == ["base", "screen"]
    assert len(card["shards"]) == len(plan(make_config("laptop", 8, 6, seed=3, test_fraction=0.25, shard_size=16,
                                                                    val_fraction=0.0)))
    assert card["rejections"]["total"] == int((m["attempts"] - 1).sum())
    assert len(card["dataset_hash"]) == 64


def _arrays(path):
    return load(path, "all").arrays()


def test_identical_output_for_identical_config_any_worker_count(tmp_path):
    cfg = make_config("scissors", 3, 4, seed=1, shard_size=5)
    generate(cfg, tmp_path / "a", progress=False)
    generate(cfg, tmp_path / "b", workers=2, progress=False)
    a, b = _arrays(tmp_path / "a"), _arrays(tmp_path / "b")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    ca = json.loads((tmp_path / "a" / "card.json").read_text())
    cb = json.loads((tmp_path / "b" / "card.json").read_text())
    assert ca == cb


class Interrupt(Exception):
    pass


def test_interrupted_generate_resumes_without_loss_or_duplicates(tmp_path):
    cfg = make_config("safe", 4, 5, seed=2, shard_size=3)
    n_shards = len(plan(cfg))
    done = []

    def stop_after_two(name):
        done.append(name)
        if len(done) == 2:
            raise Interrupt

    with pytest.raises(Interrupt):
        generate(cfg, tmp_path / "d", progress=False, on_shard_done=stop_after_two)
    written = sorted(p.name for p in (tmp_path / "d" / "shards").glob("*.npz"))
    assert len(written) == 2 and not (tmp_path / "d" / "card.json").exists()
    with pytest.raises(DatasetError, match="generation unfinished"):
        load(tmp_path / "d")
    # a half-written temporary file from a killed process is never taken for a shard
    (tmp_path / "d" / "shards" / ".train-00009.npz.tmp-123").write_bytes(b"partial")
    rep = generate(cfg, tmp_path / "d", progress=False)
    assert rep.skipped_shards == 2 and rep.rendered == cfg.instances * cfg.views - 2 * 3
    assert not list((tmp_path / "d" / "shards").glob(".*tmp*"))
    generate(cfg, tmp_path / "clean", progress=False)
    a, b = _arrays(tmp_path / "d"), _arrays(tmp_path / "clean")
    assert len(a["points"]) == cfg.instances * cfg.views and n_shards == len(list((tmp_path / "d" / "shards").glob("*.npz")))
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # running again is a no-op
    assert generate(cfg, tmp_path / "d", progress=False).rendered == 0


def test_corrupted_shard_is_named_on_load(tmp_path, laptop_data):
    d = tmp_path / "copy"
    shutil.copytree(laptop_data, d)
    shard = sorted((d / "shards").glob("train-*.npz"))[0]
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0xFF
    shard.write_bytes(bytes(data))
    ds = load(d, "train")
    with pytest.raises(CorruptShardError, match=shard.name):
        ds[0]
    shard.write_bytes(b"not a zip file")
    with pytest.raises(CorruptShardError, match=shard.name):
        load(d, "train", verify=False)[0]


def test_config_mismatch_and_bad_names(tmp_path, laptop_data):
    d = tmp_path / "copy"
    shutil.copytree(laptop_data, d)
    with pytest.raises(ConfigError, match="different config"):
        generate(make_config("laptop", 8, 7, seed=3, test_fraction=0.25, shard_size=16), d, progress=False)
    with pytest.raises(UnknownNameError, match="known: basket"):
        make_config("toaster", 2, 2)
    with pytest.raises(ConfigError, match="unknown sensor"):
        make_config("laptop", 2, 2, sensor="lidar")
    with pytest.raises(DatasetError, match="not a scapo dataset"):
        load(tmp_path / "nothing")


def test_choices_on_val_never_read_the_test_split(tmp_path, monkeypatch):
    from scapo.bench import choose_on_val
    from scapo.eval import evaluate
    from scapo.methods import run_method

    d = tmp_path / "d"
    generate(make_config("laptop", 6, 2, seed=1, test_fraction=0.2, val_fraction=0.2), d, progress=False)
    # two ICP candidates that differ in their iterations (one hypothesis set and a small template: quick)
    quick = {"refine_top": 1, "hypotheses": "T", "template_points": 64}
    files = {v: [run_method("icp", d, tmp_path / f"p{v}.npz", max_iterations=int(v), **quick)] for v in ("1", "30")}
    expected = {v: evaluate(d, f[0], split="val").summary for v, f in files.items()}  # brute force, by hand
    import scapo.data.dataset as dataset_module

    opened = []
    real = dataset_module.ArticulationDataset.__init__

    def record(self, root, split="train", *a, **k):
        opened.append(split)
        real(self, root, split, *a, **k)

    monkeypatch.setattr(dataset_module.ArticulationDataset, "__init__", record)
    chosen, rows = choose_on_val(d, files, "D+R")
    assert "test" not in opened and "val" in opened
    scores = {v: s["D"] + s["R"] for v, s in expected.items()}
    assert chosen == min(scores, key=scores.get)
    assert {r["value"]: r["score"] for r in rows} == pytest.approx(scores)
    from scapo.cli.main import main

    assert main(["bench", "choose", "--data", str(d), "--candidate", f"1={tmp_path}/p1.npz", "--candidate",
                 f"30={tmp_path}/p30.npz", "--out", str(tmp_path / "choice.json")]) == 0
    choice = json.loads((tmp_path / "choice.json").read_text())
    assert choice["chosen"] == chosen and choice["split"] == "val" and "commit" in choice["provenance"]
    assert main(["bench", "choose", "--data", str(d), "--candidate", f"1={tmp_path}/none*.npz"]) == 2

    # several datasets (one choice for the categories of a table): the mean of the per-dataset scores
    d2 = tmp_path / "d2"
    generate(make_config("laptop", 6, 2, seed=2, test_fraction=0.2, val_fraction=0.2), d2, progress=False)
    for v in ("1", "30"):
        run_method("icp", d2, d2 / f"p{v}.npz", max_iterations=int(v), **quick)
        (tmp_path / f"p{v}.npz").rename(d / f"p{v}.npz")
    scores2 = {v: evaluate(d2, d2 / f"p{v}.npz", split="val").summary for v in ("1", "30")}
    scores2 = {v: s["D"] + s["R"] for v, s in scores2.items()}
    out = tmp_path / "choice2.json"
    assert main(["bench", "choose", "--data", str(d), "--data", str(d2), "--candidate", "1={data}/p1.npz",
                 "--candidate", "30={data}/p30.npz", "--out", str(out)]) == 0
    choice = json.loads(out.read_text())
    mean = {v: (scores[v] + scores2[v]) / 2 for v in scores}
    assert choice["chosen"] == min(mean, key=mean.get)
    for row in choice["candidates"]:
        assert row["score"] == pytest.approx(mean[row["value"]])
        assert [p["score"] for p in row["per_dataset"]] == pytest.approx([scores[row["value"]], scores2[row["value"]]])
    # a GLOB without {data} is ambiguous with several datasets; a dataset without files is named
    assert main(["bench", "choose", "--data", str(d), "--data", str(d2), "--candidate", f"1={d}/p1.npz"]) == 2
    assert main(["bench", "choose", "--data", str(d), "--data", str(tmp_path), "--candidate", "1={data}/p1.npz"]) == 2


def test_a_config_written_before_the_crop_rule_and_sensor_fields_keeps_its_hash():
    """Table 1's datasets (config.json written before ``cropped`` and the sensor's range, depth crop, flying and
    ground fields existed) read back to the same JSON, so they resume and keep their hash."""
    from pathlib import Path

    from scapo.data import GenerateConfig

    text = (Path(__file__).parent / "data" / "config_before_crop_rule.json").read_text()
    old = json.loads(text)
    cfg = GenerateConfig.from_dict(old)
    assert cfg.render.cropped == "keep" and json.loads(cfg.to_json()) == old
    assert json.loads(make_config("laptop", 80, 16, 1, cropped="keep").to_json()) == old
    assert "cropped" in json.loads(make_config("laptop", 80, 16, 1).to_json())["render"]  # new default: reject
    real = json.loads(make_config("laptop", 80, 16, 1, sensor="realistic").to_json())["render"]["sensor"]
    assert {"max_range", "depth_margin", "flying", "ground"} <= set(real)


def test_cropped_views_flagged_in_the_manifest(tmp_path):
    cfg = make_config("safe", 2, 6, seed=2, test_fraction=0.5, val_fraction=0.0, cropped="flag")
    generate(cfg, tmp_path / "d", progress=False)
    m = pd.read_parquet(tmp_path / "d" / "manifest.parquet")
    assert m["cropped"].dtype == bool and len(m) == 12 and 0 < m["cropped"].sum() < 12  # safe doors leave the image
    keep = make_config("safe", 2, 6, seed=2, test_fraction=0.5, val_fraction=0.0, cropped="keep")
    generate(keep, tmp_path / "k", progress=False)
    np.testing.assert_array_equal(_arrays(tmp_path / "d")["points"], _arrays(tmp_path / "k")["points"])
    assert "cropped" not in pd.read_parquet(tmp_path / "k" / "manifest.parquet")
