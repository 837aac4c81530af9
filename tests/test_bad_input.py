"""Every mistake a user can make ends in a clear ``scapo:`` error: no traceback, no silent wrong result,
nothing already written lost (issue 11). ``tests/README.md`` lists the entry points and the cases."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import warnings

import numpy as np
import pytest
import torch
from quick import QUICK_ICP

from scapo.cli.main import main
from scapo.data import generate, load, make_config
from scapo.errors import (
    ConfigError,
    DatasetError,
    InputError,
    OutputError,
    PredictionError,
    StaleAssetsError,
    TrainingError,
)
from scapo.eval import Predictions, evaluate
from scapo.files import FolderLock
from scapo.models import load as load_model
from scapo.models.presets import PRESETS
from scapo.models.train import Trainer

TEST = PRESETS.get("test")
#: A folder the kernel refuses to create anything in, even for root (a stand-in for a read-only mount).
READ_ONLY = "/sys/scapo-test-out"


def cli(*args: str) -> tuple[int, str, str]:
    """Run ``scapo ARGS`` in this process; returns (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def assert_clear_error(result, command: str, *fragments: str) -> str:
    """Exit 2 with one ``scapo COMMAND: error:`` message holding every fragment, and no traceback."""
    code, _, err = result
    assert code == 2, err
    assert "Traceback" not in err and "internal error" not in err, err
    last = err.replace("\r", "\n").strip().splitlines()[-1]  # after any progress bar, on a line of its own
    assert last.startswith(f"scapo {command}: error: ") and err.count(": error: ") == 1, err
    err = last
    for f in fragments:
        assert f in err, (f, err)
    return err


def dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


@pytest.fixture(scope="module")
def run(laptop_data, tmp_path_factory):
    """A finished run of the test preset on the shared laptop dataset."""
    path = tmp_path_factory.mktemp("runs") / "laptop"
    Trainer(laptop_data, path, TEST, progress=False).train()
    return path


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """Three tiny datasets: laptop seed 0 and seed 1 (same plan, other samples), safe (same structure)."""
    root = tmp_path_factory.mktemp("small")
    for name, cat, seed in (("lap0", "laptop", 0), ("lap1", "laptop", 1), ("safe", "safe", 0)):
        generate(make_config(cat, 3, 2, seed=seed, shard_size=2, test_fraction=0.34, val_fraction=0.0), root / name,
                 progress=False)
    return root


def oracle_file(data, path, **edit) -> str:
    """Ground truth of test and train splits written as predictions (``needs_alignment``), with edits."""
    parts = []
    for split in ("test", "train"):
        ds = load(data, split)
        a = ds.arrays()
        parts.append(dict(instance_id=a["instance_id"], view_id=a["view_id"], split=np.full(len(ds), split),
                          part_label=a["part_label"], part_pose=a["part_pose"], joint_parts=a["joint_parts"],
                          joint_type=a["joint_type"], joint_axis=a["joint_axis"], joint_pivot=a["joint_pivot"],
                          joint_state=a["joint_state"], T_cam_obj=a["T_cam_obj"]))
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    for k, fn in edit.items():
        arrays[k] = fn(arrays[k].copy())
    meta = {"method": "oracle", "needs_alignment": True, "supervision": {}, "info": {},
            "dataset_hash": load(data, "test").dataset_hash, "format": "scapo-predictions-1"}
    np.savez(path, meta=np.array(json.dumps(meta)), **{k: (v.astype("U8") if k == "split" else v)
                                                        for k, v in arrays.items()})
    return str(path)


# ------------------------------------------------------------------ silent wrong results and data loss
def test_resume_rerenders_a_foreign_shard_instead_of_blessing_it(small, tmp_path):
    d = tmp_path / "d"
    shutil.copytree(small / "lap0", d)
    shard = sorted((d / "shards").glob("train-*.npz"))[0]
    good = shard.read_bytes()
    card = json.loads((d / "card.json").read_text())
    shutil.copy(small / "lap1" / "shards" / shard.name, shard)  # same keys, another seed's samples
    assert load(d, "train").card["dataset_hash"] == card["dataset_hash"]
    with pytest.raises(Exception, match="corrupted"):
        load(d, "train").arrays()  # the loader refuses it ...
    code, out, err = cli("generate", "--category", "laptop", "--instances", 3, "--views", 2, "--seed", 0,
                         "--shard-size", 2, "--test-fraction", 0.34, "--val-fraction", 0, "--out", d, "--no-progress")
    assert code == 0, err
    assert f"{shard.stem} (modified)" in err and "re-rendered 1 shard" in out  # ... and generate re-renders it
    assert shard.read_bytes() == good
    assert json.loads((d / "card.json").read_text()) == card
    assert (d / "rejected" / f"{shard.stem}.modified.npz").is_file()  # the foreign file is kept aside, not lost


def test_resume_of_an_unfinished_dataset_verifies_shards_against_the_journal(small, tmp_path):
    d = tmp_path / "d"
    shutil.copytree(small / "lap0", d)
    (d / "card.json").unlink()  # as if interrupted before the card was written
    (d / "manifest.parquet").unlink()
    shard = sorted((d / "shards").glob("train-*.npz"))[1]
    good = shard.read_bytes()
    shutil.copy(small / "lap1" / "shards" / shard.name, shard)
    rep = generate(make_config("laptop", 3, 2, seed=0, shard_size=2, test_fraction=0.34, val_fraction=0.0), d, progress=False)
    assert rep.rejected_shards == [shard.stem] and rep.rendered == 2
    assert shard.read_bytes() == good
    # a shard written by a process killed before it was recorded is re-rendered; identical ones are not kept aside
    lines = (d / "shards.jsonl").read_text().splitlines()
    (d / "shards.jsonl").write_text("\n".join(x for x in lines if shard.stem not in x) + "\n")
    (d / "card.json").unlink()
    rep = generate(make_config("laptop", 3, 2, seed=0, shard_size=2, test_fraction=0.34, val_fraction=0.0), d, progress=False)
    assert rep.rendered == 2 and rep.rejected_shards == [] and shard.read_bytes() == good


def test_tampered_asset_cache_is_rebuilt_not_rendered(tmp_path):
    cache = tmp_path / "cache"
    cfg = make_config("laptop", 2, 2, seed=5, shard_size=4, test_fraction=0.5)
    generate(cfg, tmp_path / "clean", progress=False, cache_dir=cache)
    obj = next(cache.rglob("screen.obj"))
    lines = obj.read_text().splitlines()
    obj.write_text("\n".join(x for i, x in enumerate(lines) if not (x.startswith("f ") and i % 2)) + "\n")
    from scapo.errors import ScapoWarning

    with pytest.warns(ScapoWarning, match="was modified after it was built"):  # said (the CLI prints one line)
        generate(cfg, tmp_path / "again", progress=False, cache_dir=cache)
    a, b = load(tmp_path / "clean", "all").arrays(), load(tmp_path / "again", "all").arrays()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_assets_that_changed_since_the_finished_shards_are_refused(small, tmp_path):
    d = tmp_path / "d"
    shutil.copytree(small / "lap0", d)
    lines = [json.loads(x) for x in (d / "shards.jsonl").read_text().splitlines()]
    start = [x for x in lines if "assets" in x][-1]
    start["assets"]["1"] = "0" * 64  # the shards were rendered from other assets
    with open(d / "shards.jsonl", "a") as f:
        f.write(json.dumps(start) + "\n")
    with pytest.raises(StaleAssetsError, match=r"assets of instance\(s\) 1 differ"):  # a ConfigError
        generate(make_config("laptop", 3, 2, seed=0, shard_size=2, test_fraction=0.34, val_fraction=0.0), d, progress=False)


def test_the_demo_moves_the_outputs_of_older_assets_aside_and_starts_afresh(tmp_path, monkeypatch, capsys):
    """A demo folder rendered from older assets (scapo upgraded since) makes generate raise StaleAssetsError; the
    demo moves that version's files into ``older-<time>/`` (nothing is lost, other files stay) and renders again."""
    import scapo.data
    from scapo.bench.demo import retire_stale_outputs, run_demo

    out = tmp_path / "demo"
    for name in ("data/card.json", "run_scapo_demo/checkpoint.pt", "predictions_icp.npz", "table1_demo.md",
                 "figure_demo_icp.png", "notes.txt"):
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(name)
    calls = []

    class Stop(Exception):
        pass

    def fake_generate(cfg, data, **kw):
        calls.append(data)
        if len(calls) == 1:
            raise StaleAssetsError(f"{data}: the assets of instance(s) 0 differ")
        assert not data.exists()  # the second call renders into an empty place
        raise Stop

    monkeypatch.setattr(scapo.data, "generate", fake_generate)
    with pytest.raises(Stop):
        run_demo(out, instances=4, views=2, preset="test")
    older = [p for p in out.iterdir() if p.name.startswith("older-")]
    assert len(calls) == 2 and len(older) == 1 and "demo of older assets" in capsys.readouterr().out
    moved = sorted(str(p.relative_to(older[0])) for p in older[0].rglob("*") if p.is_file())
    assert moved == ["data/card.json", "figure_demo_icp.png", "predictions_icp.npz", "run_scapo_demo/checkpoint.pt",
                     "table1_demo.md"]
    assert (out / "notes.txt").read_text() == "notes.txt"  # not the demo's: left where it was
    assert retire_stale_outputs(out) is None  # nothing of the demo's left to move


def test_predict_refuses_a_run_of_another_category(run, small, laptop_data, tmp_path):
    eye = tmp_path / "eye"
    generate(make_config("eyeglasses", 2, 2, seed=0, test_fraction=0.5), eye, progress=False)
    out = tmp_path / "p.npz"
    assert_clear_error(cli("predict", "--run", run, "--data", eye, "--out", out), "predict",
                       "trained on 'laptop'", "'eyeglasses'", "3 parts")
    assert_clear_error(cli("predict", "--run", run, "--data", small / "safe", "--out", out), "predict",
                       "trained on 'laptop'", "'safe'", "cross_category=true")
    assert not out.exists()
    code, _, err = cli("predict", "--run", run, "--data", small / "safe", "--out", out, "--option",
                       "cross_category=true")
    assert code == 0, err
    assert Predictions.load(out).info["trained_category"] == "laptop"


def test_a_mistyped_run_is_an_error_and_trains_nothing(laptop_data, tmp_path):
    err = assert_clear_error(cli("predict", "--run", tmp_path / "typo", "--data", laptop_data, "--out",
                                 tmp_path / "p.npz"), "predict", "typo", "scapo train")
    assert "does not exist" in err and not (tmp_path / "typo").exists() and not (tmp_path / "p.npz").exists()


def test_train_refuses_another_preset_or_dataset_before_writing_anything(run, small, laptop_data, tmp_path):
    r = tmp_path / "r"
    shutil.copytree(run, r)
    before = {p.name: p.read_bytes() for p in r.iterdir() if p.is_file()}
    assert_clear_error(cli("train", "--data", laptop_data, "--preset", "demo", "--out", r), "train",
                       "trained with preset 'test'")
    assert_clear_error(cli("train", "--data", small / "safe", "--preset", "test", "--out", r), "train",
                       "'laptop' dataset", "'safe' dataset")
    assert {p.name: p.read_bytes() for p in r.iterdir() if p.is_file()} == before
    # a run folder whose first epoch never finished (run.json, no checkpoint) is protected too
    (r / "checkpoint.pt").unlink()
    assert_clear_error(cli("train", "--data", small / "safe", "--preset", "test", "--out", r), "train",
                       "run started with preset 'test'")
    assert (r / "run.json").read_bytes() == before["run.json"]


EDITS = {
    "zero-length joint axis": ("joint_axis", lambda a: a * 0.0, "joint_axis must hold unit vectors"),
    "label below -1": ("part_label", lambda a: np.where(np.arange(a.shape[1]) == 3, -5, a), "part_label must be -1"),
    "float labels": ("part_label", lambda a: a.astype(np.float32) + 0.4, "must hold integers"),
    "non-rigid part pose": ("part_pose", lambda a: a * np.array([2.0, 1, 1, 1])[None, None, :, None],
                            "must hold rigid transforms"),
    "mirrored object pose": ("T_cam_obj", lambda a: a @ np.diag([-1.0, 1, 1, 1]), "det +1"),
    "joint axis of 2 numbers": ("joint_axis", lambda a: a[..., :2], "expected (M, 1, 3)"),
    "joint pivot of 4 numbers": ("joint_pivot", lambda a: np.concatenate([a, a[..., :1]], -1), "expected (M, 1, 3)"),
    "joint type 7": ("joint_type", lambda a: a + 7, "joint_type must be 0"),
    "NaN state": ("joint_state", lambda a: a * np.nan, "NaN/inf"),
    "object 1e300 m away": ("T_cam_obj", lambda a: a + np.pad(np.full((len(a), 3, 1), 1e300), ((0, 0), (0, 1), (3, 0))),
                            "more than 10000 m from the camera"),
    "pivot 1e300 m away": ("joint_pivot", lambda a: a + 1e300, "more than 10000 m from the camera"),
    "duplicate samples": ("view_id", lambda a: np.where(np.arange(len(a)) == 1, a[0], a), "duplicate samples"),
}


@pytest.mark.parametrize("case", list(EDITS))
def test_evaluate_validates_predictions_naming_field_and_sample(laptop_data, tmp_path, case):
    field, fn, fragment = EDITS[case]
    path = oracle_file(laptop_data, tmp_path / "p.npz", **{field: fn})
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", path), "evaluate", field, fragment)
    with pytest.raises(PredictionError, match=field):
        evaluate(laptop_data, path)


def test_the_untouched_oracle_file_evaluates_perfectly(laptop_data, tmp_path):
    res = evaluate(laptop_data, oracle_file(laptop_data, tmp_path / "p.npz"))
    assert res.summary["S"] == pytest.approx(100.0) and res.summary["D"] == pytest.approx(0.0, abs=1e-6)


POINTS = {
    "5 points": (np.random.default_rng(0).normal(size=(1, 5, 3)), "at least 64 points"),
    "0 points": (np.zeros((1, 0, 3)), "at least 64 points"),
    "batch of 0": (np.zeros((0, 1024, 3)), "empty batch"),
    "1024 identical points": (np.ones((1, 1024, 3)), "within 0.1 mm"),
    "collinear points": (np.linspace(0, 1, 3 * 300).reshape(1, 300, 3) * [1.0, 2.0, 3.0], "on one line"),
    "one cloud without batch axis": (np.random.default_rng(0).normal(size=(300, 3)), "e.g. points[None]"),
    "(B, N, 2)": (np.zeros((1, 300, 2)), "shape (B, N, 3)"),
    "NaN point": (np.where(np.arange(300)[None, :, None] == 7, np.nan, np.ones((2, 300, 3))), "cloud(s) [0, 1]"),
    "strings": (np.array([[["a", "b", "c"]] * 100]), "numeric array"),
}


@pytest.mark.parametrize("case", list(POINTS))
def test_predictor_defines_its_accepted_input(run, case):
    pts, fragment = POINTS[case]
    model = load_model(run)
    with pytest.raises(InputError, match=fragment.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        model.predict(pts)


def test_predictor_subsamples_large_clouds_with_a_warning(run):
    model = load_model(run, refine_steps=0)
    rng = np.random.default_rng(1)
    pts = (rng.normal(size=(1, 100_000, 3)) * [0.2, 0.1, 0.05] + [0, 0, 1.5]).astype(np.float32)
    with pytest.warns(UserWarning, match="subsampled to 4096"):
        out = model.predict(pts)
    assert out["part_label"].shape == (1, 100_000) and out["weights"].shape == (1, 100_000, 2)
    assert out["canonical_shape"].shape == (1, 100_000, 3) and out["part_pose"].shape == (1, 2, 4, 4)
    assert np.isfinite(out["joint_axis"]).all()


def test_unwritable_predict_output_fails_before_any_work(laptop_data, tmp_path, monkeypatch):
    from scapo.methods.icp import ICPBaseline

    def never(*a, **k):
        raise AssertionError("fit ran although the output cannot be written")

    monkeypatch.setattr(ICPBaseline, "fit", never)
    (tmp_path / "dir.npz").mkdir()
    for out, fragment in ((READ_ONLY + "/p.npz", "cannot be created"), (tmp_path / "dir.npz", "existing folder"),
                          (tmp_path / "file" / "p.npz", "is a file")):
        (tmp_path / "file").write_text("x")
        assert_clear_error(cli("predict", "--method", "icp", "--data", laptop_data, "--out", out), "predict",
                           fragment)


# ------------------------------------------------------------------ tracebacks turned into clear errors
def test_generate_argument_errors(tmp_path):
    base = ["generate", "--category", "laptop", "--instances", 2, "--views", 2, "--no-progress"]
    assert_clear_error(cli(*base, "--points", 8, "--out", tmp_path / "a"), "generate", "must be >= 16, got 8")
    assert_clear_error(cli(*base, "--width", 8, "--height", 8, "--out", tmp_path / "b"), "generate",
                       "8 x 8 pixels", "raise --width/--height")
    assert_clear_error(cli(*base, "--workers", 0, "--out", tmp_path / "c"), "generate", "workers must be >= 1")
    assert_clear_error(cli(*base[:4], 0, *base[5:], "--out", tmp_path / "d"), "generate", "must be >= 1")
    assert_clear_error(cli(*base, "--sensor", "lidar", "--out", tmp_path / "e"), "generate", "unknown sensor")
    assert_clear_error(cli(*base, "--seed", -1, "--out", tmp_path / "f"), "generate", "seed must be >= 0")
    # --width 0 was silently replaced by the default width
    assert_clear_error(cli(*base, "--width", 0, "--out", tmp_path / "g"), "generate", "at least 1 x 1", "0 x 256")
    assert not any((tmp_path / x).exists() for x in "abcdefg")


def test_all_views_rejected_names_the_real_cause(tmp_path):
    err = assert_clear_error(cli("generate", "--category", "laptop", "--instances", 2, "--views", 1, "--width", 40,
                                 "--height", 40, "--out", tmp_path / "d", "--no-progress"), "generate",
                             "too few object pixels", "raise --width/--height")
    assert "widen the view ranges" not in err


@pytest.mark.parametrize("command", ["generate", "train", "predict", "evaluate"])
def test_out_that_is_a_file_or_read_only(command, laptop_data, run, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("mine")
    args = {"generate": ["--category", "laptop", "--instances", 2, "--views", 2, "--no-progress"],
            "train": ["--data", laptop_data, "--preset", "test", "--no-progress"],
            "predict": ["--run", run, "--data", laptop_data],
            "evaluate": ["--data", laptop_data, "--pred", oracle_file(laptop_data, tmp_path / "p.npz")]}[command]
    for out, fragment in ((afile / "sub", "is a file"), (READ_ONLY, "choose a writable location")):
        assert_clear_error(cli(command, *args, "--out", out), command, fragment)
    if command != "predict":  # a file where a folder is expected (predict writes a file)
        assert_clear_error(cli(command, *args, "--out", afile), command, str(afile))
    assert afile.read_text() == "mine"


def test_unusable_asset_cache(tmp_path, monkeypatch):
    afile = tmp_path / "afile"
    afile.write_text("x")
    for cache, fragment in ((afile, "is a file"), (READ_ONLY, "cannot be written")):
        monkeypatch.setenv("SCAPO_CACHE", str(cache))
        assert_clear_error(cli("generate", "--category", "laptop", "--instances", 2, "--views", 2, "--out",
                               tmp_path / "d", "--no-progress"), "generate", "SCAPO_CACHE", fragment)
        assert_clear_error(cli("assets", "build", "--category", "laptop", "--instances", 1), "assets", fragment)
    assert_clear_error(cli("assets", "build", "--category", "laptop", "--instances", 0), "assets", ">= 1")


def test_truncated_card_and_config(laptop_data, run, tmp_path):
    d = tmp_path / "d"
    shutil.copytree(laptop_data, d)
    (d / "card.json").write_text('{"category": "lap')
    for command, args in (("evaluate", ["--pred", "x.npz"]), ("predict", ["--method", "icp", "--out", tmp_path / "p"]),
                          ("train", ["--out", tmp_path / "r", "--preset", "test"]), ("preview", [])):
        assert_clear_error(cli(command, "--data", d, *args), command, "card.json is not valid JSON")
    (d / "card.json").write_text('{"category": "laptop"}')
    with pytest.raises(DatasetError, match="lacks"):
        load(d)
    (d / "config.json").write_text("")
    assert_clear_error(cli("generate", "--category", "laptop", "--instances", 8, "--views", 6, "--seed", 3, "--out",
                           d), "generate", "config.json is empty", "delete that file")
    (d / "manifest.parquet").write_bytes(b"PAR1 broken")


def test_config_mismatch_names_only_the_differing_fields(small, tmp_path):
    d = tmp_path / "d"
    shutil.copytree(small / "lap0", d)
    with pytest.raises(ConfigError) as e:
        generate(make_config("laptop", 3, 3, seed=0, shard_size=2, test_fraction=0.34, val_fraction=0.0), d, progress=False)
    assert "differs in views)" in str(e.value) and "view." not in str(e.value)
    with pytest.raises(ConfigError, match=r"differs in render\.num_points\)"):
        generate(make_config("laptop", 3, 2, seed=0, shard_size=2, test_fraction=0.34, num_points=512, val_fraction=0.0), d,
                 progress=False)


def test_corrupt_or_truncated_checkpoint_through_predict(run, laptop_data, tmp_path):
    for name, data in (("garbage", b"not a checkpoint"), ("truncated", (run / "checkpoint.pt").read_bytes()[:5000])):
        r = tmp_path / name
        shutil.copytree(run, r)
        (r / "checkpoint.pt").write_bytes(data)
        assert_clear_error(cli("predict", "--run", r, "--data", laptop_data, "--out", tmp_path / "p.npz"), "predict",
                           "cannot be loaded", "checkpoint.pt")
        with pytest.raises(TrainingError, match="cannot be loaded"):
            load_model(r)
    afile = tmp_path / "f"
    afile.write_text("x")
    with pytest.raises(TrainingError, match="it is a file"):
        load_model(afile)


@pytest.mark.parametrize("device,fragment", [("cuda", "use --device cpu"), ("foo", "unknown device 'foo'"),
                                             ("cuda:7", "device"), ("mps", "not supported")])
def test_unavailable_or_unknown_devices(device, fragment, run, laptop_data, tmp_path):
    if torch.cuda.is_available() and device.startswith("cuda") and device != "cuda:7":
        pytest.skip("this machine has CUDA")
    assert_clear_error(cli("train", "--data", laptop_data, "--preset", "test", "--out", tmp_path / "r", "--device",
                           device, "--no-progress"), "train", fragment)
    assert_clear_error(cli("predict", "--run", run, "--data", laptop_data, "--out", tmp_path / "p.npz", "--device",
                           device), "predict", fragment)
    with pytest.raises(ConfigError):
        load_model(run, device=device)
    assert not (tmp_path / "r").exists()


def test_method_options_are_validated_listing_the_valid_ones(laptop_data, run, tmp_path):
    out = tmp_path / "p.npz"
    base = ["predict", "--data", laptop_data, "--out", out]
    assert_clear_error(cli(*base, "--method", "icp", "--option", "foo=1"), "predict", "unknown option 'foo'",
                       "valid options: template_points, hypotheses, max_iterations")
    assert_clear_error(cli(*base, "--method", "icp", "--option", "max_iterations=abc"), "predict",
                       "max_iterations='abc'", "not a valid int")
    assert_clear_error(cli(*base, "--method", "icp", "--option", "max_iterations=0"), "predict",
                       "max_iterations=0")
    assert_clear_error(cli(*base, "--method", "icp", "--option", "hypotheses=Z"), "predict", "hypotheses in I, O, T")
    assert_clear_error(cli(*base, "--method", "icp", "--option", "progress"), "predict", "--set 'progress' is not of the form FIELD=VALUE")
    assert_clear_error(cli(*base, "--run", run, "--option", "refine_steps=-1"), "predict", "refine_steps must be >= 0")
    assert_clear_error(cli(*base, "--run", run, "--option", "preset=cpu"), "predict", "unknown option 'preset'",
                       "valid options: run, device")
    assert_clear_error(cli(*base, "--run", run, "--option", "cross_category=maybe"), "predict", "not a valid bool")
    assert not out.exists()


def test_an_empty_test_split_is_named(tmp_path):
    d = tmp_path / "d"
    code, _, err = cli("generate", "--category", "laptop", "--instances", 2, "--views", 2, "--test-fraction", 0,
                       "--out", d, "--no-progress")
    assert code == 0 and "the test split is empty" in err
    assert_clear_error(cli("predict", "--method", "icp", "--data", d, "--out", tmp_path / "p.npz"), "predict",
                       "test split", "is empty")
    assert_clear_error(cli("evaluate", "--data", d, "--pred", tmp_path / "p.npz"), "evaluate", "test split",
                       "is empty")


def test_two_generates_on_one_folder_are_refused_by_a_lock(tmp_path):
    d = tmp_path / "d"
    d.mkdir()
    cfg = make_config("laptop", 2, 2)
    with FolderLock(d, "generate"):  # another process writing the dataset (flock conflicts across open files)
        with pytest.raises(OutputError, match=r"in use by scapo generate \(pid \d+"):
            generate(cfg, d, progress=False)
        assert_clear_error(cli("generate", "--category", "laptop", "--instances", 2, "--views", 2, "--out", d),
                           "generate", "in use by")
    assert generate(cfg, d, progress=False).samples == 4  # released: works


def test_two_trainings_on_one_run_are_refused_by_a_lock(run, laptop_data, tmp_path):
    r = tmp_path / "r"
    shutil.copytree(run, r)
    with FolderLock(r, "train"):
        assert_clear_error(cli("train", "--data", laptop_data, "--preset", "test", "--out", r), "train",
                           "in use by scapo train")
    assert cli("train", "--data", laptop_data, "--out", r)[0] == 0  # released; its own preset, already finished


def test_folders_that_are_not_ours_are_not_written_into(laptop_data, tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("x")
    assert_clear_error(cli("generate", "--category", "laptop", "--instances", 2, "--views", 2, "--out", mine),
                       "generate", "non-empty folder without a scapo dataset", "thesis.tex")
    assert_clear_error(cli("train", "--data", laptop_data, "--preset", "test", "--out", laptop_data), "train",
                       "non-empty folder without a scapo run")
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.tex"]


def test_ctrl_c_names_what_is_kept_per_command(monkeypatch, laptop_data, tmp_path):
    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr("scapo.engine.lifecycle.train", interrupt)
    code, _, err = cli("train", "--data", laptop_data, "--preset", "test", "--out", tmp_path / "r")
    assert code == 130 and "last finished epoch is kept" in err and "shards" not in err
    monkeypatch.setattr("scapo.methods.run_method", interrupt)
    code, _, err = cli("predict", "--method", "icp", "--data", laptop_data, "--out", tmp_path / "p.npz")
    assert code == 130 and "nothing was written" in err


def test_a_bug_is_one_line_not_a_traceback(monkeypatch, laptop_data, tmp_path):
    def bug(*a, **k):
        raise TypeError("unsupported operand")

    monkeypatch.setattr("scapo.methods.run_method", bug)
    code, _, err = cli("predict", "--method", "icp", "--data", laptop_data, "--out", tmp_path / "p.npz")
    assert code == 3 and "internal error (TypeError: unsupported operand)" in err and "Traceback" not in err


def test_temporaries_of_killed_processes_are_cleaned(run, laptop_data, tmp_path):
    pid = dead_pid()
    cache = tmp_path / "cache"
    generate(make_config("laptop", 2, 2, test_fraction=0.5), tmp_path / "d", progress=False, cache_dir=cache)
    seed_dir = next(cache.rglob("seed0"))
    stale_build = seed_dir / f".00001.tmp-{pid}-abc"
    stale_build.mkdir()
    (stale_build / "model.urdf").write_text("half")
    stale = [tmp_path / "d" / f".card.json.tmp-{pid}", tmp_path / "d" / "shards" / f".test-00000.npz.tmp-{pid}"]
    r = tmp_path / "r"
    shutil.copytree(run, r)
    stale.append(r / f".checkpoint.pt.tmp-{pid}")
    stale.append(tmp_path / f".p.npz.tmp-{pid}")
    for p in stale:
        p.write_bytes(b"partial")
    generate(make_config("laptop", 2, 2, test_fraction=0.5), tmp_path / "d", progress=False, cache_dir=cache)
    Trainer(laptop_data, r, TEST, progress=False).train()
    assert cli("predict", "--run", r, "--data", laptop_data, "--out", tmp_path / "p.npz")[0] == 0
    assert not stale_build.exists() and not any(p.exists() for p in stale)


def test_resume_drops_the_log_rows_of_the_interrupted_epoch(laptop_data, tmp_path):
    import dataclasses

    import pandas as pd

    p = dataclasses.replace(TEST, stage1_epochs=2, stage2_epochs=1)
    from unittest import mock

    from scapo.engine import loop as engine_fit

    t = Trainer(laptop_data, tmp_path / "r", p, progress=False)
    orig = engine_fit.run_epoch

    def stop_mid_epoch(job, st, ep, *a):
        if (st.index, ep) == (1, 1):
            with open(tmp_path / "r" / "log.csv", "a") as f:  # a row of the epoch, then the interruption
                f.write("1,1,0,0.001,1.0" + "," * 14 + "\n1,1,1,0.0")
            raise KeyboardInterrupt
        return orig(job, st, ep, *a)

    with mock.patch.object(engine_fit, "run_epoch", stop_mid_epoch), pytest.raises(KeyboardInterrupt):
        t.train()
    Trainer(laptop_data, tmp_path / "r", p, progress=False).train()
    log = pd.read_csv(tmp_path / "r" / "log.csv")
    assert not log.duplicated(["stage", "epoch", "step"]).any()
    assert (log.groupby(["stage", "epoch"]).size() == 2).all() and len(log) == 6


def test_realistic_sensor_is_quiet(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        generate(make_config("laptop", 2, 1, sensor="realistic", test_fraction=0.5), tmp_path / "d", progress=False)


def test_loader_and_other_entry_points(laptop_data, tmp_path):
    afile = tmp_path / "f"
    afile.write_text("x")
    with pytest.raises(DatasetError, match="it is a file"):
        load(afile)
    d = tmp_path / "d"
    shutil.copytree(laptop_data, d)
    card = json.loads((d / "card.json").read_text())
    card["shards"].pop("train-00000")
    (d / "card.json").write_text(json.dumps(card))
    with pytest.raises(DatasetError, match="train-00000 .* is not listed in card.json"):
        load(d, "train")[0]
    (d / "manifest.parquet").write_bytes(b"PAR1 broken")
    with pytest.raises(DatasetError, match="manifest.parquet cannot be read"):
        load(d)
    assert_clear_error(cli("preview", "--data", laptop_data, "--count", 0), "preview", "--count must be >= 1")
    assert_clear_error(cli("preview", "--data", laptop_data, "--out", tmp_path), "preview", "existing folder")
    assert_clear_error(cli("bench", "perf", "--workers", "0", "--out", tmp_path / "b"), "bench", ">= 1")
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", tmp_path / "none.npz"), "evaluate",
                       "does not exist")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK not a zip")
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", bad), "evaluate", "cannot be read")
    np.savez(bad, meta=np.array("{broken"), **{k: np.zeros(1) for k in (
        "instance_id", "view_id", "split", "part_label", "part_pose", "joint_parts", "joint_type", "joint_axis",
        "joint_pivot", "joint_state", "T_cam_obj")})
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", bad), "evaluate", "unreadable header")
    assert os.path.exists(laptop_data / "card.json")
    # preview: an empty split, a truncated config.json
    d2 = tmp_path / "d2"
    shutil.copytree(laptop_data, d2)
    (d2 / "config.json").write_text('{"category": ')
    assert_clear_error(cli("preview", "--data", d2, "--out", tmp_path / "p.png"), "preview", "config.json is not valid")
    empty = tmp_path / "empty"
    generate(make_config("laptop", 2, 1, test_fraction=0.0), empty, progress=False)
    assert_clear_error(cli("preview", "--data", empty, "--out", tmp_path / "p.png"), "preview", "test split",
                       "is empty")


def test_names_are_checked_before_any_work(tmp_path):
    assert_clear_error(cli("bench", "perf", "--what", "model", "--preset", "test", "--device", "foo"), "bench",
                       "unknown device 'foo'")
    assert_clear_error(cli("demo", "--out", tmp_path / "demo", "--preset", "huge"), "demo", "unknown preset 'huge'")
    assert_clear_error(cli("bench", "table1", "--methods", "nope", "--categories", "laptop", "--work", tmp_path / "w"),
                       "bench", "unknown method 'nope'")
    assert_clear_error(cli("bench", "table1", "--categories", "laptop,teapot", "--work", tmp_path / "w"), "bench",
                       "unknown category 'teapot'")
    assert not (tmp_path / "demo").exists() and not (tmp_path / "w").exists()


def test_perf_growth_command_writes_its_rows(tmp_path, capsys):
    """The cost-growth benchmark runs end to end on tiny sizes (its timings are measured by scapo bench perf, not
    judged here)."""
    from scapo.cli.main import main

    assert main(["bench", "perf", "--what", "growth", "--sizes", "20,40", "--workers", "1", "--out",
                 str(tmp_path / "perf")]) == 0
    rows = json.loads((tmp_path / "perf" / "growth_laptop.json").read_text())["rows"]
    assert [r["samples"] for r in rows] == [20, 40] and "generate_growth_exponent" in rows[1]
    assert rows[1]["test_samples"] > 0


def test_outputs_never_leave_out_or_land_in_a_dataset_or_run_folder(laptop_data, run, tmp_path):
    """One ownership rule for every writer: a ``--name`` stays inside ``--out``; no table, report or image is written
    into a dataset or run folder (their card, run.json or checkpoint could be replaced); an existing file is replaced
    only by an output of its own kind (its mark)."""
    import shutil

    preds = tmp_path / "p.npz"
    assert cli("predict", "--method", "icp", "--data", laptop_data, "--out", preds, *QUICK_ICP)[0] == 0
    for name in ("../escaped", "a/b", ".hidden", ""):
        assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", preds, "--out", tmp_path / "t", "--name",
                               name), "evaluate", "must be a plain file name")
    assert not (tmp_path / "escaped.json").exists()
    data = tmp_path / "data"
    shutil.copytree(laptop_data, data)
    card = (data / "card.json").read_bytes()
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", preds, "--out", data, "--name", "card"),
                       "evaluate", "is a scapo dataset folder")
    assert (data / "card.json").read_bytes() == card
    r = tmp_path / "run"
    shutil.copytree(run, r)
    ident = (r / "run.json").read_bytes()
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", preds, "--out", r, "--name", "run"),
                       "evaluate", "is a scapo run folder")
    assert (r / "run.json").read_bytes() == ident
    notes = tmp_path / "t" / "notes.json"
    notes.parent.mkdir(exist_ok=True)
    notes.write_text('{"provenance": "my notes, not a table"}')
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", preds, "--out", tmp_path / "t", "--name",
                           "notes"), "evaluate", "notes.json exists and was not written by scapo")
    assert notes.read_text() == '{"provenance": "my notes, not a table"}'
    assert cli("evaluate", "--data", laptop_data, "--pred", preds, "--out", tmp_path / "t", "--name", "mine")[0] == 0
    assert json.loads((tmp_path / "t" / "mine.json").read_text())["scapo_output"] == "scapo table"
    assert cli("evaluate", "--data", laptop_data, "--pred", preds, "--out", tmp_path / "t", "--name", "mine")[0] == 0
    assert_clear_error(cli("assets", "symmetry", "--category", "laptop", "--instances", "1", "--views", "1",
                           "--json", data / "card.json"), "assets", "scapo dataset folder")
    mine = tmp_path / "notes.json"
    mine.write_text('{"provenance": "my own notes"}')
    assert_clear_error(cli("assets", "symmetry", "--category", "laptop", "--instances", "1", "--views", "1",
                           "--json", mine), "assets", "exists and is not a symmetry report")
    photo = tmp_path / "holiday.png"
    photo.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    assert_clear_error(cli("preview", "--data", laptop_data, "--out", photo), "preview", "is not a preview image")
    assert mine.read_text() == '{"provenance": "my own notes"}' and photo.read_bytes().endswith(b"not really")


def test_an_output_of_its_own_kind_is_replaced(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scapo.errors import OutputError
    from scapo.files import atomic_savefig, check_output_owned_file, output_mark, write_json

    png, js = tmp_path / "p.png", tmp_path / "s.json"
    atomic_savefig(plt.figure(), png, metadata=output_mark("scapo preview"))
    write_json(js, {**output_mark("scapo assets symmetry"), "x": 1})
    assert check_output_owned_file(png, "scapo preview", "preview image", "preview.png") == png
    assert check_output_owned_file(js, "scapo assets symmetry", "symmetry report", "symmetry.json") == js
    with pytest.raises(OutputError, match="is not a preview image"):  # another kind's mark is not this kind's
        check_output_owned_file(png, "scapo twin", "preview image", "preview.png")


def test_statistics_and_lists_that_would_mislead_are_refused(laptop_data, run, tmp_path):
    """Two predictions files of one run are not two training seeds; an empty --categories / --methods does not mean
    "everything"; a candidate value given twice is not silently dropped; seeds and folders are checked before any
    dataset is rendered, and the dry run checks what the real run checks."""
    p1, p2 = tmp_path / "a.npz", tmp_path / "b.npz"
    assert cli("predict", "--run", run, "--data", laptop_data, "--out", p1)[0] == 0
    assert cli("predict", "--run", run, "--data", laptop_data, "--out", p2, "--option", "refine_steps=0")[0] == 0
    assert_clear_error(cli("evaluate", "--data", laptop_data, "--pred", p1, "--pred", p2), "evaluate",
                       "are predictions of one run")
    for flag in ("--categories", "--methods"):
        for empty in ("", ","):
            err = io.StringIO()
            with contextlib.redirect_stderr(err), pytest.raises(SystemExit) as exit_:  # argparse's usage error
                main(["bench", "table1", flag, empty, "--dry-run", "--work", str(tmp_path / "w")])
            assert exit_.value.code == 2 and "names nothing" in err.getvalue() and "Traceback" not in err.getvalue()
    assert_clear_error(cli("bench", "choose", "--data", laptop_data, "--candidate", f"1={p1}", "--candidate",
                           f"1={p2}"), "bench", "is given twice")
    for dry in ((), ("--dry-run",)):
        assert_clear_error(cli("bench", "table1", "--seeds", "-1", "--categories", "laptop", "--work",
                               tmp_path / "w", *dry), "bench", "training seeds must be integers")
        assert not (tmp_path / "w").exists()
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    assert_clear_error(cli("bench", "table1", "--dry-run", "--work", a_file), "bench", "is (or is inside) a file")


def test_ranges_and_indices_that_would_mislead_are_refused(laptop_data, tmp_path):
    from scapo.data import load

    assert_clear_error(cli("generate", "--category", "laptop", "--instances", "2", "--views", "1", "--azimuth",
                           "nan,nan", "--out", tmp_path / "d"), "generate", "both ends must be finite")
    base = ["generate", "--category", "laptop", "--instances", "2", "--views", "1"]
    for extra, fragment in ((["--width", "100000", "--height", "100000"], "at most 4096 pixels a side"),
                            (["--num-envs", "0"], "--num-envs must be >= 1"),
                            (["--backend", "maniskill", "--num-envs", "4"], "ManiSkill")):
        if "maniskill" in extra and __import__("torch").cuda.is_available():
            continue  # with a GPU, parallel sub-scenes are legitimate
        out = tmp_path / f"g{len(extra)}{extra[-1]}"
        err = assert_clear_error(cli(*base, *extra, "--out", out), "generate", fragment)
        assert not out.exists(), err  # refused before the folder (config, lock, journal) is touched
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    assert_clear_error(cli("bench", "table1", "--dry-run", "--archive", a_file, "--work", tmp_path / "w"), "bench",
                       "--archive")
    ds = load(laptop_data, "test")
    for bad in (1.5, "1", True):
        with pytest.raises(TypeError, match="must be an integer"):
            ds[bad]
    assert ds[np.int64(1)]["view_id"] == ds[1]["view_id"]


def test_predictions_files_and_options_that_would_be_guessed_at_are_refused(small, tmp_path):
    """A predictions file with arrays scapo does not write is refused, not half-read; ``--option run=`` is the
    ``--run`` flag; the viewer, like the evaluator, shows predictions of its own dataset only."""
    import numpy as np

    preds = tmp_path / "p.npz"
    assert cli("predict", "--method", "icp", "--data", small / "lap0", "--out", preds, *QUICK_ICP)[0] == 0
    arrays = dict(np.load(preds, allow_pickle=False))
    np.savez(tmp_path / "extra.npz", **arrays, extra_thing=np.zeros(3))
    assert_clear_error(cli("evaluate", "--data", small / "lap0", "--pred", tmp_path / "extra.npz"), "evaluate",
                       "holds arrays a scapo predictions file has not (extra_thing)")
    (tmp_path / "notes.npz").write_text("not an archive")
    err = assert_clear_error(cli("evaluate", "--data", small / "lap0", "--pred", tmp_path / "notes.npz"), "evaluate",
                             "it is not an .npz archive")
    assert "pickle" not in err and "unsafe" not in err
    assert_clear_error(cli("predict", "--method", "scapo", "--option", "run=somewhere", "--data", small / "lap0",
                           "--out", tmp_path / "q.npz"), "predict", "is given as --run")
    pytest.importorskip("viser")
    assert_clear_error(cli("view", "--data", small / "lap1", "--pred", preds, "--port", "0"), "view",
                       "was made on dataset")


def test_a_preset_name_date_slot_and_label_are_clear_errors(laptop_data, run, tmp_path):
    """The probe's cases: ``--set name=cpu`` once trained the ``test`` schedule under the name ``cpu``; a TOML date as
    a number and ``base_slot=²`` (``'²'.isdigit()`` is true) were internal errors; a prediction label with ``../``
    named files outside ``--out``. Each is refused before anything is written."""
    assert_clear_error(cli("train", "--method", "npcs", "--data", laptop_data, "--preset", "test", "--set", "name=cpu",
                           "--out", tmp_path / "r1"), "train", "'name' is the preset's identity", "--preset NAME")
    config = tmp_path / "c.toml"
    config.write_text("epochs = 1979-05-27\n")
    assert_clear_error(cli("train", "--method", "npcs", "--data", laptop_data, "--preset", "test", "--config", config,
                           "--out", tmp_path / "r2"), "train", "epochs=datetime.date(1979, 5, 27) is not a valid int")
    assert not (tmp_path / "r1").exists() and not (tmp_path / "r2" / "checkpoint.pt").exists()
    assert_clear_error(cli("predict", "--run", run, "--data", laptop_data, "--option", "base_slot=²", "--out",
                           tmp_path / "p.npz"), "predict", "base_slot must be a part slot number or 'auto'")
    assert_clear_error(cli("predict", "--run", run, "--data", laptop_data, "--option", "label=../../esc", "--out",
                           tmp_path / "p.npz"), "predict", "label '../../esc' must be a plain file name")
    assert not (tmp_path / "p.npz").exists()


def test_a_damaged_run_json_is_named_not_the_checkpoint(laptop_data, run, tmp_path):
    """A truncated or ``[]`` ``run.json`` once ended in "KeyError: 'model_config' ... delete the damaged file first",
    pointing at the healthy checkpoint: prediction reads the checkpoint alone and succeeds; training into the folder
    names ``run.json``; the checkpoint is kept."""
    for text in ('{"method": "sca', "[]"):
        copy = tmp_path / f"run{len(text)}"
        shutil.copytree(run, copy)
        (copy / "run.json").write_text(text)
        code, _, err = cli("predict", "--run", copy, "--data", laptop_data, "--out", tmp_path / f"p{len(text)}.npz")
        assert code == 0, err
        assert_clear_error(cli("train", "--data", laptop_data, "--out", copy), "train", "run.json is damaged",
                           "Give --preset NAME")
        assert (copy / "checkpoint.pt").is_file()


def test_predictions_of_another_run_are_not_replaced_and_an_option_is_given_once(laptop_data, run, tmp_path):
    """``scapo predict --out`` once replaced another run's predictions file without a word; the same run's file is
    replaced (a rerun); a repeated ``--option`` key once let the last win."""
    out = tmp_path / "p.npz"
    assert cli("predict", "--method", "icp", "--data", laptop_data, "--out", out, *QUICK_ICP)[0] == 0
    before = out.read_bytes()
    assert_clear_error(cli("predict", "--run", run, "--data", laptop_data, "--out", out), "predict",
                       "holds the predictions of icp (a fitted method), not of scapo from run", "give another --out")
    assert out.read_bytes() == before
    assert cli("predict", "--run", run, "--data", laptop_data, "--out", tmp_path / "q.npz")[0] == 0
    assert cli("predict", "--run", run, "--data", laptop_data, "--out", tmp_path / "q.npz")[0] == 0  # a rerun
    assert_clear_error(cli("predict", "--run", run, "--data", laptop_data, "--option", "base_slot=0", "--option",
                           "base_slot=1", "--out", tmp_path / "r.npz"), "predict",
                       "--set base_slot is given twice ('0' and '1')")
    # one override syntax: predict takes --set FIELD=VALUE as train does (--option is its alias)
    assert_clear_error(cli("predict", "--run", run, "--data", laptop_data, "--set", "refine_steps", "--out",
                           tmp_path / "s.npz"), "predict", "--set 'refine_steps' is not of the form FIELD=VALUE")
    assert cli("predict", "--run", run, "--data", laptop_data, "--set", "refine_steps=0", "--set",
               "label=scapo-one-pass", "--out", tmp_path / "s.npz")[0] == 0
    from scapo.eval import Predictions

    assert Predictions.load(tmp_path / "s.npz").method == "scapo-one-pass"


def test_the_python_api_refuses_a_run_whose_weights_are_nan(run, tmp_path):
    """``scapo.methods.load(run).predict_points`` once returned NaN poses without a word for a checkpoint whose
    weights are NaN (the command line refused it); loading it is now a ``TrainingError`` naming a tensor."""
    import scapo.methods

    copy = tmp_path / "nan_run"
    shutil.copytree(run, copy)
    state = torch.load(copy / "checkpoint.pt", weights_only=False)
    name = next(k for k, v in state["model"].items() if v.is_floating_point())
    state["model"][name] = torch.full_like(state["model"][name], float("nan"))
    torch.save(state, copy / "checkpoint.pt")
    with pytest.raises(TrainingError, match=rf"weights hold NaN or infinite values \(1 tensor\(s\), first: {name}\)"):
        scapo.methods.load(copy)


def test_stage2_starts_on_a_run_without_the_parts_frame_is_refused(laptop_data, run, tmp_path):
    """``--option stage2_starts=O`` on a run whose stage 2 does not train in the parts frame tried no start but
    labelled the rows ``+starts-O``; it is refused naming the preset part it needs ("off" stays allowed)."""
    assert_clear_error(cli("predict", "--run", run, "--data", laptop_data, "--option", "stage2_starts=O", "--out",
                           tmp_path / "p.npz"), "predict", "stage2_starts=O applies to a run trained with "
                       "stage2_frame='parts'")
    assert not (tmp_path / "p.npz").exists()
