"""What a user meets first: the installed package, loading any method's run, configuration from the command line
and files, warnings about small data, data files that carry code."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from scapo.cli.main import main
from scapo.errors import ConfigError, ScapoWarning, TrainingError
from scapo.methods import METHODS, train_method

PIN = Path(__file__).parent / "data" / "pin_laptop"  # 4 train and 2 test laptops
ROOT = Path(__file__).resolve().parents[1]


def run_cli(*args) -> tuple[int, str, str]:
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


@pytest.mark.slow
def test_the_wheel_in_a_fresh_venv_reports_its_version_lists_and_generates_from_another_folder(tmp_path):
    """(Also what tests/test_install.py checked: a non-editable install carries the category templates and builds
    assets anywhere.)"""
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                        str(dist), str(ROOT)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    (wheel,) = dist.glob("scapo-*.whl")
    venv = tmp_path / "venv"
    # a venv without its own pip (ensurepip costs 6 s of CPU); this environment's pip installs into it, run from
    # tmp_path: from the checkout, a PYTHONPATH with an empty entry showed pip the checkout's scapo.egg-info as an
    # installed scapo and it installed nothing
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "--no-deps",
                        "-q", str(wheel)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    # then the dependencies from this environment (no network for a second torch); scapo only from the wheel.
    # (Added after the install: a pip that saw this environment's scapo would uninstall it.)
    site = next(venv.glob("lib/python*/site-packages"))
    deps = [p for p in sys.path if p.endswith("site-packages") and Path(p, "torch").is_dir()]
    (site / "deps.pth").write_text("\n".join(deps) + "\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path), "SCAPO_CACHE": str(tmp_path / "cache")}
    scapo = str(venv / "bin" / "scapo")

    def run(*args):
        return subprocess.run([scapo, *args], capture_output=True, text=True, timeout=600, env=env, cwd=elsewhere)

    v = run("--version")
    assert v.returncode == 0 and v.stdout.strip().startswith("scapo 0.") and "dirty" not in v.stdout, v
    assert "(v0." in v.stdout  # outside a git checkout, provenance names the installed version
    ls = run("list")
    assert ls.returncode == 0 and "laptop" in ls.stdout and "scapo" in ls.stdout, ls.stderr[-2000:]
    g = run("generate", "--category", "laptop", "--instances", "2", "--views", "1", "--test-fraction", "0.5",
            "--val-fraction", "0", "--points", "256", "--out", "d", "--no-progress")
    assert g.returncode == 0, g.stderr[-2000:]
    assert json.loads((elsewhere / "d" / "card.json").read_text())["category"] == "laptop"
    imported = subprocess.run([str(venv / "bin" / "python"), "-c", "import scapo; print(scapo.__file__)"],
                              capture_output=True, text=True, env=env, cwd=elsewhere)
    assert str(venv) in imported.stdout  # the wheel's copy, not the checkout
    # the package data came with it (the category templates that built the assets above)
    assert (Path(imported.stdout.strip()).parent / "sim_assets" / "categories" / "laptop.toml").is_file()


def test_version_and_provenance_outside_a_checkout(monkeypatch):
    from scapo import provenance

    with pytest.raises(SystemExit):
        main(["--version"])
    provenance.git_commit.cache_clear()
    monkeypatch.setattr(provenance.subprocess, "run", lambda *a, **k: (_ for _ in ()).throw(OSError("no git")))
    try:
        assert provenance.git_commit() == f"v{provenance.package_version()}"
    finally:
        provenance.git_commit.cache_clear()
    from scapo.bench.cells import dirty_sha

    assert not dirty_sha(f"v{provenance.package_version()}")  # a release is not uncommitted code


@pytest.fixture(scope="module")
def runs(trained_test_runs):
    """Every trained method's ``test``-preset run on the session's small laptop dataset (conftest.py; PIN's
    laptops are of the same category, so these runs predict on them)."""
    return trained_test_runs


def test_methods_load_round_trips_every_trained_method(runs):
    """``scapo.methods.load(run)`` gives each trained method's predictor: its nn.Module, and the same outputs as
    the predictions ``scapo predict`` writes."""
    from scapo.data import load as load_data
    from scapo.methods import load, run_method

    pts = load_data(PIN, "test").arrays(["points"])["points"]
    for name, run in runs.items():
        m = load(run, device="cpu")
        assert isinstance(m.module, torch.nn.Module) and not m.module.training
        out = m.predict_points(pts)
        preds = run_method(name, PIN, None, run=run, device="cpu")
        test = preds.split == "test"
        np.testing.assert_allclose(out["part_pose"], preds.part_pose[test], atol=1e-5, err_msg=name)
        np.testing.assert_array_equal(out["part_label"], preds.part_label[test], err_msg=name)


def test_model_load_names_the_method_of_another_run_and_a_damaged_checkpoint_is_said_so(runs, tmp_path):
    import scapo.models
    from scapo.methods import load

    with pytest.raises(ConfigError, match="a run of method 'npcs', not SCAPO; load it with scapo.methods.load"):
        scapo.models.load(runs["npcs"])
    for name in ("npcs", "scapo"):
        bad = tmp_path / name
        bad.mkdir()
        (bad / "run.json").write_text((runs[name] / "run.json").read_text())
        (bad / "checkpoint.pt").write_bytes((runs[name] / "checkpoint.pt").read_bytes()[:300])
        with pytest.raises(TrainingError, match="cannot be (read|loaded)"):
            load(bad)
    with pytest.raises(TrainingError, match="does not exist"):
        load(tmp_path / "nowhere")


class _Payload:
    def __reduce__(self):
        return (os.system, (f"touch {Path(os.environ.get('TMPDIR', '/tmp')) / 'scapo-pwned'}",))


def test_checkpoints_and_frame_files_are_read_without_running_their_code(runs, tmp_path):
    from scapo.data.opalign_real import read_frame
    from scapo.errors import DatasetError
    from scapo.methods import load

    flag = Path(os.environ.get("TMPDIR", "/tmp")) / "scapo-pwned"
    flag.unlink(missing_ok=True)
    for name in ("npcs", "scapo"):
        evil = tmp_path / f"evil_{name}"
        evil.mkdir()
        (evil / "run.json").write_text((runs[name] / "run.json").read_text())
        state = torch.load(runs[name] / "checkpoint.pt", weights_only=True)
        state["payload"] = _Payload()
        torch.save(state, evil / "checkpoint.pt")
        with pytest.raises(TrainingError):
            load(evil)
        code, _, err = run_cli("predict", "--run", evil, "--data", PIN, "--out", tmp_path / "p.npz")
        assert code == 2 and "scapo predict: error:" in err
    np.savez(tmp_path / "frame.npz", np.array({"pc": _Payload()}, dtype=object))
    with pytest.raises(DatasetError, match="may not"):
        read_frame(tmp_path / "frame.npz")
    assert not flag.exists()


def test_set_and_config_override_preset_fields_and_are_recorded(tmp_path):
    run = tmp_path / "r"
    code, _, err = run_cli("train", "--data", PIN, "--preset", "test", "--set", "stage1_epochs=2", "--set",
                           "losses.seg=2.5", "--out", run, "--no-progress")
    assert code == 0, err
    preset = json.loads((run / "run.json").read_text())["preset"]
    assert preset["stage1_epochs"] == 2 and preset["losses"]["seg"] == 2.5
    # the same folder without the override is another run
    code, _, err = run_cli("train", "--data", PIN, "--preset", "test", "--out", run, "--no-progress")
    assert code == 2 and "preset fields that differ: losses.seg, stage1_epochs" in err
    cfg = tmp_path / "npcs.toml"
    cfg.write_text("epochs = 3\nlr = 0.002\n")
    code, _, err = run_cli("train", "--method", "npcs", "--data", PIN, "--preset", "test", "--config", cfg,
                           "--set", "lr=0.003", "--out", tmp_path / "n", "--no-progress")
    assert code == 0, err
    preset = json.loads((tmp_path / "n" / "run.json").read_text())["preset"]
    assert preset["epochs"] == 3 and preset["lr"] == 0.003  # --set after --config


@pytest.mark.parametrize("args,fragment", [
    (["--set", "stage1_epochz=2"], "unknown scapo preset field 'stage1_epochz'; valid fields: name, stage1_epochs"),
    (["--set", "stage1_epochs=two"], "stage1_epochs='two' is not a valid int"),
    (["--set", "stage1_epochs"], "is not of the form KEY=VALUE"),
    (["--set", "losses=3"], "'losses' is a group of settings"),
    (["--set", "losses.nope=1"], "unknown scapo preset losses field 'nope'"),
    (["--set", "part_init=maybe"], "part_init='maybe' is not a valid bool"),
    (["--set", "batch_size=0"], "invalid"),
    (["--config", "missing.toml"], "no such file"),
    (["--set", "lr_stage1=nan"], "invalid lr_stage1: must be a finite number"),
    (["--set", "lr_stage1=-1"], "invalid lr_stage1: must be > 0"),
    (["--set", "lr_stage1=inf"], "invalid lr_stage1: must be a finite number"),
    (["--set", "lr_stage2=inf"], "invalid lr_stage2: must be a finite number"),
    (["--set", "weight_decay=-1"], "invalid weight_decay: must be >= 0"),
    (["--set", "gamma=0"], "invalid gamma: must be > 0"),
    (["--set", "template_points=0"], "invalid template_points"),
    (["--set", "encoder.k=0"], "invalid k"),
    (["--set", "encoder.rot_channels="], "rot_channels"),
    (["--set", "losses.seg=nan"], "invalid seg"),
    (["--set", "max_steps_per_epoch=-1"], "invalid max_steps_per_epoch"),
    (["--set", "stage1_epochs=0", "--set", "stage2_epochs=0"], "nothing would be trained"),
    (["--set", "train_points=100000"], "clouds have 256"),
    (["--seed", "1", "--set", "seed=5"], "given twice"),
    (["--set", "anchors=X"], "anchors must be"),
    (["--set", "encoder.decoder_hidden=512"], "give two widths"),
    (["--set", "batch_size=100000"], "no training step would run"),
    (["--set", "min_lr=1"], "exceeds a stage's learning rate"),
    (["--set", "refine.lr=nan"], "must be finite numbers"),
    (["--set", "name="], "'name' is the preset's identity"),
    (["--set", "template_points=100000"], "lower template_points"),
])
def test_bad_overrides_are_clear_errors_before_anything_is_written(args, fragment, tmp_path):
    code, _, err = run_cli("train", "--data", PIN, "--preset", "test", *args, "--out", tmp_path / "r", "--no-progress")
    assert code == 2 and fragment in err and "Traceback" not in err, err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("method", ["npcs", "eap", "op-align"])
def test_the_baselines_presets_meet_the_same_checks(method, tmp_path):
    for kv, fragment in (("lr=inf", "lr"), ("weight_decay=-1", "invalid weight_decay"), ("grad_clip=nan", "grad_clip"),
                         ("min_lr=-1", "invalid min_lr"), ("min_lr=1", "exceeds lr"),
                         ("batch_size=100000", "no training step would run")):
        code, _, err = run_cli("train", "--method", method, "--data", PIN, "--preset", "test", "--set", kv, "--out",
                               tmp_path / "r", "--no-progress")
        assert code == 2 and fragment in err and "Traceback" not in err, (kv, err)
        assert not (tmp_path / "r").exists()


def test_bad_config_files_are_clear_errors(tmp_path):
    for name, text, fragment in [("a.toml", "epochs = [", "not valid TOML"), ("a.json", "{}", "give a .toml"),
                                 ("b.toml", "epochs = 'x'", "is not a valid int"),
                                 ("c.toml", "[nope]\nx = 1", "unknown npcs preset field 'nope'"),
                                 ("d.yaml", "epochs: 3\nepochs: 4\n", "gives the key 'epochs' twice"),
                                 ("e.toml", '"a.b" = 1\n[a]\nb = 2\n', "gives 'a.b' twice")]:
        (tmp_path / name).write_text(text)
        code, _, err = run_cli("train", "--method", "npcs", "--data", PIN, "--preset", "test", "--config",
                               tmp_path / name, "--out", tmp_path / "r", "--no-progress")
        assert code == 2 and fragment in err, (name, err)


def test_tensorboard_events_beside_the_log(tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    train_method("npcs", PIN, tmp_path / "r", "test", progress=False)
    (events,) = (tmp_path / "r" / "tensorboard").glob("events.*")
    acc = EventAccumulator(str(events))
    acc.Reload()
    assert "stage1/total" in acc.Tags()["scalars"] and len(acc.Scalars("stage1/total")) == 4


def test_small_splits_are_warned_about_in_training_and_scoring(tmp_path):
    from scapo.eval import evaluate
    from scapo.methods import run_method

    with pytest.warns(ScapoWarning, match="train split .* holds only 4 instance"):
        preds = run_method("icp", PIN, tmp_path / "p.npz", **METHODS.get("icp").quick_options)
    with pytest.warns(ScapoWarning, match="test split .* holds only 2 instance"):
        res = evaluate(PIN, preds)
    assert res.info["instances"] == 2
    code, _, err = run_cli("evaluate", "--data", PIN, "--pred", tmp_path / "p.npz")
    assert code == 0 and "scapo evaluate: warning: the test split" in err


def test_every_command_takes_no_progress():
    import argparse

    from scapo.cli.main import build_parser

    def leaves(parser, prefix=()):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sp in a.choices.items():
                    if any(isinstance(x, argparse._SubParsersAction) for x in sp._actions):
                        yield from leaves(sp, (*prefix, name))
                    else:
                        yield (*prefix, name), sp

    for name, sp in leaves(build_parser()):
        assert any("--no-progress" in a.option_strings for a in sp._actions), name
    assert "TQDM_DISABLE" not in os.environ  # a command leaves the process's environment as it found it


# ---------------------------------------------------------------------------------------------- bad input
@pytest.fixture
def pin_copy(tmp_path):
    import shutil

    shutil.copytree(PIN, tmp_path / "pin")
    return tmp_path / "pin"


def assert_error(result, command: str, *fragments: str) -> str:
    code, _, err = result
    assert code == 2, err
    assert "Traceback" not in err and "internal error" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"scapo {command}: error: "), err
    for f in fragments:
        assert f in last, (f, last)
    return last


def test_outputs_never_replace_files_of_another_kind(pin_copy, runs, tmp_path):
    before = {p: p.read_bytes() for p in pin_copy.rglob("*") if p.is_file()}
    shard = next((pin_copy / "shards").glob("*.npz"))
    for target in (pin_copy / "card.json", runs["npcs"] / "checkpoint.pt", shard):
        assert_error(run_cli("predict", "--method", "icp", "--data", pin_copy, "--out", target), "predict",
                     "exists and is not a predictions file")
    assert {p: p.read_bytes() for p in pin_copy.rglob("*") if p.is_file()} == before
    # a predictions file is replaced by a new one
    assert run_cli("predict", "--run", runs["npcs"], "--data", pin_copy, "--out", tmp_path / "p.npz")[0] == 0
    assert run_cli("predict", "--run", runs["npcs"], "--data", pin_copy, "--out", tmp_path / "p.npz")[0] == 0
    # evaluate --out: a folder whose table1.md scapo did not write
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "table1.md").write_text("my notes")
    assert_error(run_cli("evaluate", "--data", pin_copy, "--pred", tmp_path / "p.npz", "--out", tmp_path / "mine"),
                 "evaluate", "table1.md exists and was not written by scapo")
    assert (tmp_path / "mine" / "table1.md").read_text() == "my notes"
    assert run_cli("evaluate", "--data", pin_copy, "--pred", tmp_path / "p.npz", "--out", tmp_path / "t")[0] == 0
    assert run_cli("evaluate", "--data", pin_copy, "--pred", tmp_path / "p.npz", "--out", tmp_path / "t")[0] == 0
    # the same predictions twice are not two seeds
    import shutil

    shutil.copy(tmp_path / "p.npz", tmp_path / "q.npz")
    assert_error(run_cli("evaluate", "--data", pin_copy, "--pred", tmp_path / "p.npz", "--pred", tmp_path / "q.npz"),
                 "evaluate", "are the same predictions")
    assert_error(run_cli("evaluate", "--data", pin_copy, "--pred", tmp_path / "p.npz", "--twin", "--twin-limit",
                         "-3"), "evaluate", "--twin-limit must be >= 0")
    assert_error(run_cli("preview", "--data", pin_copy, "--out", tmp_path / "x.txt"), "preview", "must end in .png")
    assert not (tmp_path / "x.txt").exists()


def test_predictions_without_a_dataset_hash_are_not_scored(pin_copy, tmp_path):
    from scapo.errors import PredictionError
    from scapo.eval import Predictions, evaluate
    from scapo.methods import run_method

    preds = run_method("icp", pin_copy, None, **METHODS.get("icp").quick_options)
    preds = Predictions(**{**preds.__dict__, "dataset_hash": ""})
    with pytest.raises(PredictionError, match="carry no dataset hash"):
        evaluate(pin_copy, preds)


@pytest.mark.parametrize("args,fragment", [
    (["--workers", "10000"], "use at most"),
    (["--instances", "1000000000000"], "beyond what one dataset holds"),
    (["--seed", str(2 ** 66)], "seed must be >= 0 and < 2**63"),
])
def test_generate_refuses_what_would_hang_or_overflow(args, fragment, tmp_path):
    base = {"--category": "laptop", "--instances": "2", "--views": "1"}
    for k, v in zip(args[::2], args[1::2]):
        base[k] = v
    argv = [x for kv in base.items() for x in kv]
    assert_error(run_cli("generate", *argv, "--out", tmp_path / "d", "--no-progress"), "generate", fragment)
    assert not (tmp_path / "d").exists() or not any((tmp_path / "d").iterdir())


def test_training_refuses_seeds_beyond_32_bits(tmp_path):
    assert_error(run_cli("train", "--data", PIN, "--preset", "test", "--seed", str(2 ** 66), "--out", tmp_path / "r"),
                 "train", "training seed must be an integer in [0, 2**32)")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("args,fragment", [
    (["--port", "-5"], "a port is a number in 1..65535"),
    (["--port", "70000"], "a port is a number in 1..65535"),
    (["--host", "999.1.1.1"], "is not an address or name this machine knows"),
])
def test_the_viewer_checks_where_it_listens_before_it_starts(args, fragment):
    pytest.importorskip("viser")
    assert_error(run_cli("view", "--data", PIN, *args), "view", fragment)


def test_bench_refuses_repeated_names_and_zero_sizes(tmp_path):
    kw = ["--work", tmp_path / "w", "--dry-run", "--preset", "test"]
    assert_error(run_cli("bench", "table1", "--methods", "icp,icp", *kw), "bench", "names icp more than once")
    assert_error(run_cli("bench", "table1", "--instances", "0", *kw), "bench", "must be >= 1")


@pytest.mark.parametrize("view,fragment", [
    ({"azimuth_deg": [300, 10]}, "low <= high"),
    ({"azimuth_deg": "abc"}, "is not a range"),
    ({"azimuth_deg": [0, 10, 20]}, "is not a range"),
    ({"distance": [0, 1]}, "must be positive"),
    ({"target_jitter": -1}, "non-negative"),
    ({"azimuth": [0, 10]}, "unknown view field"),
])
def test_per_object_view_options_are_checked(view, fragment):
    from scapo.sim.assets.objects import view_overrides

    with pytest.raises(ConfigError, match=fragment):
        view_overrides(view)
    assert view_overrides({"azimuth_deg": [-30, 30]}) == (("azimuth_deg", (-30.0, 30.0)),)


def test_misspelled_per_object_keys_are_refused(tmp_path, cache_dir):
    from scapo.sim.assets import build_instance

    urdf = build_instance("laptop", 0, seed=0, cache_dir=cache_dir).urdf
    opts = tmp_path / "o.json"
    opts.write_text(json.dumps({Path(urdf).parent.name: {"veiw": {"azimuth_deg": [0, 10]}}}))
    code, _, err = run_cli("generate", "--object", urdf, "--views", "1", "--object-options", opts, "--out",
                           tmp_path / "d")
    assert code == 2 and ("unknown key(s) ['veiw']" in err or "names objects that are not" in err), err


def _urdf(tmp_path, joint: str) -> Path:
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    link = '<link name="{0}"><visual><geometry><mesh filename="m.obj"/></geometry></visual></link>'
    (tmp_path / "o.urdf").write_text(f'<robot name="o">{link.format("a")}{link.format("b")}{link.format("c")}'
                                     f'{joint}</robot>')
    return tmp_path / "o.urdf"


def test_urdf_joints_that_would_be_sampled_wrongly_are_refused(tmp_path):
    from scapo.errors import URDFError
    from scapo.sim.assets import parse_urdf

    hinge = ('<joint name="j{0}" type="revolute"><parent link="a"/><child link="{1}"/><axis xyz="0 0 1"/>'
             '<limit lower="{2}" upper="{3}"/>{4}</joint>')
    wide = _urdf(tmp_path, hinge.format(1, "b", -100, 100, ""))
    with pytest.raises(URDFError, match="span more than a full turn"):
        parse_urdf(wide)
    mimic = _urdf(tmp_path, hinge.format(1, "b", 0, 1, "") + hinge.format(2, "c", 0, 1, '<mimic joint="j1"/>'))
    with pytest.raises(URDFError, match="mimic"):
        parse_urdf(mimic)
    ok = _urdf(tmp_path, hinge.format(1, "b", 0, 1, "") + hinge.format(2, "c", 0, 1, ""))
    assert parse_urdf(ok).num_joints == 2
    slide = ('<joint name="s" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="1 0 0"/>'
             '<limit lower="-1e9" upper="1e9"/></joint>')
    with pytest.raises(URDFError, match="reach beyond 100 units"):
        parse_urdf(_urdf(tmp_path, slide))
    loop = hinge.format(1, "b", 0, 1, "").replace('<parent link="a"/>', '<parent link="c"/>') + \
        hinge.format(2, "c", 0, 1, "").replace('<parent link="a"/>', '<parent link="b"/>')
    with pytest.raises(URDFError, match="form a loop"):
        parse_urdf(_urdf(tmp_path, loop))  # b and c are each other's parent (a is the root, outside the loop)
    every = hinge.format(1, "b", 0, 1, "").replace('<parent link="a"/>', '<parent link="c"/>') + \
        hinge.format(2, "c", 0, 1, "").replace('<parent link="a"/>', '<parent link="b"/>') + \
        hinge.format(3, "a", 0, 1, "").replace('<parent link="a"/>', '<parent link="b"/>')
    with pytest.raises(URDFError, match="form a loop"):
        parse_urdf(_urdf(tmp_path, every))  # every link a child: no root


def test_opalign_conversion_refuses_bad_frames_and_arguments(tmp_path):
    from scapo.data.opalign_real import convert_opalign_real, fit_intrinsics
    from scapo.errors import InputError

    with pytest.raises(ConfigError, match="--seed must be in"):
        convert_opalign_real(tmp_path, "laptop", tmp_path / "o", seed=-1)
    # an organised 48 x 64 image read as 64 x 48: the pixels do not sit where a pinhole camera puts them
    H, W, f = 48, 64, 50.0
    v, u = np.mgrid[0:H, 0:W]
    z = np.full(H * W, 2.0)
    pc = np.stack([(u.ravel() - W / 2) * z / f, (v.ravel() - H / 2) * z / f, z], 1)
    K = fit_intrinsics(pc, (H, W))
    assert K[0, 0] == pytest.approx(f)
    with pytest.raises(InputError, match="transposed"):
        fit_intrinsics(pc, (W, H))


# ---------------------------------------------------------------------------------------------- figures
def test_loss_plot_gives_every_term_its_own_style_and_labelled_axes():
    import pandas as pd

    from scapo.engine.runs import loss_figure

    terms = [f"term{k}" for k in range(13)]
    df = pd.DataFrame([{"stage": 1, "epoch": 0, "step": s, "lr": 1e-3, "total": 1.0 + s,
                        **{t: 0.1 * (k + 1) + 0.01 * s for k, t in enumerate(terms)}} for s in range(6)])
    fig = loss_figure(df)
    (ax,) = fig.axes
    styles = [(line.get_color(), line.get_linestyle()) for line in ax.get_lines()]
    assert len(styles) == 14 and len(set(styles)) == 14  # 13 terms and the total, no two alike
    assert ax.get_xlabel() and ax.get_ylabel()
    # fixed margins (no tight_layout): with one or two stages and 1e-7 .. 1e3 losses over 1,150 steps (a tick label
    # at the right end), every label and tick label is inside the figure
    for stages in ((1,), (1, 2)):
        df = pd.DataFrame([{"stage": st, "epoch": 0, "step": s, "lr": 1e-3, "total": 1e3 * 0.98 ** s,
                            "tiny": 1e-7 * (1 + s)} for st in stages for s in range(1150)])
        fig = loss_figure(df)
        renderer = fig.canvas.get_renderer()
        inside = fig.bbox.padded(1.0)
        for ax in fig.axes:
            box = ax.get_tightbbox(renderer)
            assert inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1, stages


def test_prediction_figures_colour_parts_as_the_ground_truth_and_list_only_what_is_drawn():
    from scapo.bench.viz import _axis_handles, _matched_labels

    gt = np.array([0, 0, 1, 1, 1, -1])
    pred = np.array([1, 1, 0, 0, 0, 0])  # a correct laptop with its slots in the other order
    np.testing.assert_array_equal(_matched_labels(pred, gt), [0, 0, 1, 1, 1, 1])
    assert [h.get_label() for h in _axis_handles([0])] == ["revolute axis"]
    assert [h.get_label() for h in _axis_handles([1, 0])] == ["revolute axis", "prismatic axis"]


# ---------------------------------------------------------------------------------------------- reruns
def test_a_corrected_rerun_takes_over_a_generation_that_wrote_no_shard(tmp_path):
    from scapo.data import make_config

    out = tmp_path / "d"
    (out / "shards").mkdir(parents=True)  # what a generation that failed before its first shard leaves
    (out / "config.json").write_text(make_config("laptop", 2, 1, seed=1).to_json())
    code, _, err = run_cli("generate", "--category", "laptop", "--instances", "2", "--views", "1", "--seed", "2",
                           "--test-fraction", "0.5", "--val-fraction", "0", "--out", out, "--no-progress")
    assert code == 0, err
    assert json.loads((out / "config.json").read_text())["seed"] == 2
    # a folder with rendered shards is another dataset: refused, naming the command that clears it
    assert_error(run_cli("generate", "--category", "laptop", "--instances", "2", "--views", "1", "--seed", "3",
                         "--test-fraction", "0.5", "--val-fraction", "0", "--out", out, "--no-progress"),
                 "generate", "different config", f"rm -r {out}")


def test_a_refused_run_folder_names_the_command_that_clears_it(tmp_path):
    run = tmp_path / "r"
    assert run_cli("train", "--method", "npcs", "--data", PIN, "--preset", "test", "--out", run, "--no-progress")[0] == 0
    assert_error(run_cli("train", "--method", "npcs", "--data", PIN, "--preset", "test", "--seed", "4", "--out", run),
                 "train", f"rm -r {run}")


def test_a_twin_folder_left_by_a_failed_export_is_taken_over(laptop_data, tmp_path):
    from test_twin import oracle

    from scapo.eval import Predictions
    from scapo.twin import export_twin

    out = tmp_path / "twin"
    (out / "meshes").mkdir(parents=True)
    (out / "meshes" / "part0.obj").write_text("v 0 0 0\n")  # no twin.json: the export stopped half-way
    rep = export_twin(laptop_data, oracle(laptop_data), 0, out)
    assert (out / "twin.json").is_file() and rep.parts
    assert isinstance(oracle(laptop_data), Predictions)


def test_assets_check_reads_a_built_procedural_asset_folder(cache_dir):
    from scapo.sim.assets import build_instance

    rec = build_instance("laptop", 0, seed=0, cache_dir=cache_dir)
    code, out, err = run_cli("assets", "check", Path(rec.urdf).parent)
    assert code == 0, err
    assert "category=laptop" in out and "joint" in out


def test_scapo_refuses_complex_clouds_and_clouds_in_other_units():
    from scapo.errors import InputError
    from scapo.methods.learned import check_clouds
    from scapo.models.predict import check_points

    good = np.random.default_rng(0).normal(size=(2, 100, 3)) * 0.1 + [0, 0, 1]
    for check in (check_points, check_clouds):
        with pytest.raises(InputError, match="complex"):
            check(good.astype(complex))
        with pytest.raises(InputError, match="metres"):
            check(good * 1e20)
        assert tuple(check(good).shape) == (2, 100, 3)


def test_training_on_an_object_without_a_movable_joint_is_refused(pin_copy, tmp_path):
    from scapo.data.storage import write_json

    card = json.loads((pin_copy / "card.json").read_text())
    card["joint_type"], card["joint_parts"] = [], []  # as a dataset of a rigid object's card reads
    write_json(pin_copy / "card.json", card)
    with pytest.raises(ConfigError, match="has no movable joint"):
        train_method("npcs", pin_copy, tmp_path / "r", "test", progress=False)
    assert not (tmp_path / "r").exists()


def test_progress_bars_draw_only_on_a_terminal(monkeypatch):
    """A log file or a pipe gets no carriage-return progress lines (tqdm's own check of the stream); a terminal gets
    the bar, unless ``--no-progress`` (``TQDM_DISABLE``) turned bars off."""
    import io

    from scapo.report import progress_bar

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    log = io.StringIO()
    assert list(progress_bar(range(3), file=log)) == [0, 1, 2] and log.getvalue() == ""
    term = Terminal()
    list(progress_bar(range(3), file=term))
    assert "3/3" in term.getvalue()
    monkeypatch.setenv("TQDM_DISABLE", "1")
    quiet = Terminal()
    list(progress_bar(range(3), file=quiet))
    assert quiet.getvalue() == ""


def test_a_config_that_is_a_pipe_a_device_or_a_folder_is_named_so_and_never_read(tmp_path):
    """``--config /dev/zero`` or a FIFO was called "no such file" (and reading either would never end)."""
    import os

    from scapo.config import read_config
    from scapo.errors import ConfigError

    fifo = tmp_path / "settings.toml"
    os.mkfifo(fifo)
    for path, kind in ((fifo, "not a regular file"), ("/dev/zero", "not a regular file"), (tmp_path, "a folder")):
        with pytest.raises(ConfigError, match=f"is {kind}"):
            read_config(path)


def test_a_commit_git_cannot_verify_is_never_recorded_as_a_release(monkeypatch):
    """On a loaded machine ``git status`` once timed out and the provenance said ``v0.1.0``, as if released code had
    run; a checkout's commit is now ``<sha>-unverified`` then (a table treats it as dirty), ``unknown`` when git
    cannot name the commit either."""
    import subprocess

    import scapo.provenance as prov
    from scapo.bench.cells import dirty_sha

    real = subprocess.run

    def slow_status(cmd, *a, **k):
        if cmd[:2] == ["git", "status"]:
            raise subprocess.TimeoutExpired(cmd, 120)
        return real(cmd, *a, **k)

    monkeypatch.setattr(prov.subprocess, "run", slow_status)
    commit = prov.git_commit.__wrapped__()  # past the once-per-process cache
    assert commit.endswith("-unverified") and len(commit.split("-")[0]) == 40 and dirty_sha(commit)

    def slow_git(cmd, *a, **k):
        raise subprocess.TimeoutExpired(cmd, 120)

    monkeypatch.setattr(prov.subprocess, "run", slow_git)
    commit = prov.git_commit.__wrapped__()  # past the once-per-process cache
    assert commit == "unknown" and dirty_sha(commit)
