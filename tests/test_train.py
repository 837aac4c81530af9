"""SCAPO training and inference: both stages run, resume reproduces, bad checkpoints are refused."""

import dataclasses
import shutil

import numpy as np
import pytest
import torch

import scapo.losses
from scapo.errors import TrainingError, UnknownNameError
from scapo.eval import evaluate
from scapo.methods import run_method
from scapo.models import load as load_model
from scapo.models.presets import PRESETS
from scapo.models.train import Trainer, train

TEST = PRESETS.get("test")


class Stop(Exception):
    pass


def interrupt_at(trainer: Trainer, stage: int, epoch: int) -> None:
    """Run ``trainer`` and stop it (as an interruption would) when it reaches ``(stage, epoch)``."""
    from unittest import mock

    from scapo.engine import loop as engine_fit

    orig = engine_fit.run_epoch

    def interrupted(job, st, ep, *a):
        if (st.index, ep) == (stage, epoch):
            raise Stop
        return orig(job, st, ep, *a)

    with mock.patch.object(engine_fit, "run_epoch", interrupted), pytest.raises(Stop):
        trainer.train()


@pytest.fixture(scope="module")
def finished_run(laptop_data, tmp_path_factory):
    """A finished run of the ``test`` preset (seed 0) on the shared laptop dataset; read it, or copy it first."""
    run = tmp_path_factory.mktemp("finished_run") / "run"
    Trainer(laptop_data, run, TEST, progress=False).train()
    return run


@pytest.fixture(scope="module")
def root_motion_run(laptop_data, tmp_path_factory):
    """A finished run of the ``test`` preset with ``root_motion``; read it, or copy it first."""
    run = tmp_path_factory.mktemp("root_motion_run") / "run"
    Trainer(laptop_data, run, dataclasses.replace(TEST, root_motion=True), progress=False).train()
    return run


def test_train_predict_evaluate_round_trip(laptop_data, finished_run, tmp_path):
    run = finished_run
    for f in ("checkpoint.pt", "log.csv", "losses.png", "run.json"):
        assert (run / f).is_file(), f
    pred = load_model(run)
    pts = np.random.default_rng(0).normal(size=(3, 200, 3)).astype(np.float32) * 0.1 + [0, 0, 1.5]
    out = pred.predict(pts)
    assert out["part_pose"].shape == (3, 2, 4, 4) and out["part_label"].shape == (3, 200)
    assert out["joint_axis"].shape == (3, 1, 3) and np.isfinite(out["joint_pivot"]).all()
    np.testing.assert_allclose(np.linalg.norm(out["joint_axis"], axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(out["weights"].sum(-1), 1.0, atol=1e-5)
    with pytest.raises(ValueError, match="shape"):
        pred.predict(pts[0])
    bad = pts.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        pred.predict(bad)
    preds = run_method("scapo", laptop_data, tmp_path / "p.npz", run=run)
    assert preds.needs_alignment and set(preds.split) == {"train", "test"}
    res = evaluate(laptop_data, tmp_path / "p.npz")
    for k in ("S", "D", "R", "t"):
        assert np.isfinite(res.summary[k])


def test_resume_gives_the_same_result(laptop_data, tmp_path):
    p = dataclasses.replace(TEST, stage1_epochs=2, stage2_epochs=1)
    Trainer(laptop_data, tmp_path / "a", p, progress=False).train()

    interrupt_at(Trainer(laptop_data, tmp_path / "b", p, progress=False), 1, 1)
    Trainer(laptop_data, tmp_path / "b", p, progress=False).train()  # resumes at stage 1, epoch 1
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["model"]
    b = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["model"]
    for k in a:
        torch.testing.assert_close(a[k], b[k], msg=k)


def test_checkpoint_of_another_config_is_refused(laptop_data, finished_run, tmp_path):
    shutil.copytree(finished_run, tmp_path / "r")
    Trainer(laptop_data, tmp_path / "r", TEST, progress=False).train()  # the same preset: finished, accepted
    other = dataclasses.replace(TEST, name="other", stage2_epochs=2)
    with pytest.raises(TrainingError, match="trained with preset 'test'"):
        Trainer(laptop_data, tmp_path / "r", other, progress=False).train()
    same_name = dataclasses.replace(TEST, root_motion=True, losses=dataclasses.replace(TEST.losses, seg=2.0))
    with pytest.raises(TrainingError, match=r"differ: losses\.seg, root_motion"):
        Trainer(laptop_data, tmp_path / "r", same_name, progress=False).train()
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "checkpoint.pt").write_bytes(b"garbage")
    with pytest.raises(TrainingError, match="cannot be read"):
        Trainer(laptop_data, tmp_path / "broken", TEST, progress=False).train()
    with pytest.raises(TrainingError, match="no checkpoint"):
        load_model(tmp_path / "nothing")


def test_nan_loss_stops_training_naming_the_loss(laptop_data, tmp_path, monkeypatch):
    real = scapo.losses.stage2_terms

    def poisoned(*a, **k):
        terms = real(*a, **k)
        terms["joint_prox"] = terms["joint_prox"] * float("nan")
        return terms

    monkeypatch.setattr("scapo.models.train.stage2_terms", poisoned)
    with pytest.raises(TrainingError, match="loss 'joint_prox' became nan at stage 2"):
        Trainer(laptop_data, tmp_path / "n", TEST, progress=False).train()
    # the stage-1 checkpoint written before the failure is intact and resumable
    state = torch.load(tmp_path / "n" / "checkpoint.pt", weights_only=False)
    assert state["stage"] == 2 and not state["done"]
    shutil.rmtree(tmp_path / "n")


def test_regularisers_can_be_switched_off(laptop_data, tmp_path):
    losses = dataclasses.replace(TEST.losses, disabled=("shape_var", "dir_align", "joint_prox", "joint_boundary"))
    Trainer(laptop_data, tmp_path / "abl", dataclasses.replace(TEST, name="abl", losses=losses), progress=False).train()
    import pandas as pd

    log = pd.read_csv(tmp_path / "abl" / "log.csv")
    assert log[log.stage == 2]["shape_var"].isna().all() and log[log.stage == 2]["cycle"].notna().all()
    with pytest.raises(ValueError, match="unknown regularisers"):
        dataclasses.replace(TEST.losses, disabled=("nope",))


def test_an_unfinished_run_is_refused_by_predict_and_finished_by_train_with_its_own_preset(laptop_data, tmp_path):
    p = dataclasses.replace(TEST, name="test_custom", stage1_epochs=2, stage2_epochs=1)
    interrupt_at(Trainer(laptop_data, tmp_path / "run", p, progress=False), 1, 1)
    # prediction never trains (issue 11): an unfinished run is an error naming how to resume it
    with pytest.raises(TrainingError, match="unfinished run .*scapo train"):
        run_method("scapo", laptop_data, tmp_path / "p.npz", run=tmp_path / "run")
    assert not (tmp_path / "p.npz").exists()
    assert not torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)["done"]
    # train without a preset resumes with the run's own (unregistered) preset
    train(laptop_data, tmp_path / "run", progress=False)
    assert torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)["done"]
    preds = run_method("scapo", laptop_data, tmp_path / "p.npz", run=tmp_path / "run")
    assert preds.info["preset"] == "test_custom"


def test_stage2_starts_from_the_rigid_split_of_the_canonical_clouds(laptop_data, tmp_path, small_part_search):
    p = dataclasses.replace(TEST, name="test_part_init", part_init=True, stage1_epochs=1, stage2_epochs=0)
    t = Trainer(laptop_data, tmp_path / "run", p, progress=False)
    t.train()
    from scapo.models.train import TrainingClouds

    fixed = t.model.keypoints.net[-1].bias.detach().clone()
    y0 = t.model.y_base.detach().clone()
    t.job._init_template(TrainingClouds(laptop_data, p.train_points))
    kb = t.model.keypoints.net[-1].bias.detach().view(2, 12)
    jb = t.model.joints.out[-1].bias.detach().view(1, 7)
    assert not torch.equal(kb.reshape(-1), fixed)  # keypoints moved from the fixed initialisation
    assert torch.isfinite(kb).all() and torch.isfinite(jb).all()
    assert float((kb[0, :3] - kb[1, :3]).norm()) > 0.05  # two distinct part centres
    assert float(jb[0, 3:6].norm()) == pytest.approx(1.0, abs=1e-5)  # a unit axis
    assert torch.isfinite(t.model.y_base).all() and not torch.equal(t.model.y_base, y0)  # the medoid cloud


def test_root_motion_run_round_trips_and_its_poses_are_consistent(root_motion_run):
    from scapo.ops.rigid import joint_motion

    pred = load_model(root_motion_run)
    assert pred.model.cfg.root_motion
    with torch.no_grad():  # a visible root state, so that the base really moves off the stage-1 frame
        pred.model.joints.out[-1].bias[-1] = 0.4
    pts = np.random.default_rng(0).normal(size=(2, 200, 3)).astype(np.float32) * 0.1 + [0, 0, 1.5]
    o = pred.predict(pts)
    np.testing.assert_allclose(o["T_cam_obj"], o["part_pose"][:, 0], atol=1e-6)
    for b in range(2):
        rel = o["part_pose"][b, 1] @ np.linalg.inv(o["part_pose"][b, 0])  # the child's motion, camera frame
        ref = joint_motion(0, o["joint_axis"][b, 0].astype(np.float64), o["joint_pivot"][b, 0].astype(np.float64),
                           float(o["joint_state"][b, 0]))
        np.testing.assert_allclose(rel, ref, atol=1e-4)


def test_refinement_is_an_inference_setting_and_keeps_poses_consistent(laptop_data, root_motion_run, tmp_path):
    from scapo.models.refine import RefineConfig
    from scapo.ops.rigid import joint_motion

    run = tmp_path / "run"
    shutil.copytree(root_motion_run, run)
    # another refinement setting is the same run: the finished checkpoint is accepted, not refused
    Trainer(laptop_data, run, dataclasses.replace(TEST, root_motion=True, refine=RefineConfig(steps=4)),
            progress=False).train()
    assert load_model(run).refine.steps == 0  # the run's own preset: off
    pred = load_model(run, refine_steps=8)
    assert pred.refine.steps == 8
    pts = np.random.default_rng(0).normal(size=(3, 200, 3)).astype(np.float32) * 0.1 + [0, 0, 1.5]
    plain, o = load_model(run).predict(pts), pred.predict(pts)
    assert not np.allclose(plain["part_pose"], o["part_pose"])  # the fit moved the pose
    np.testing.assert_allclose(o["weights"].sum(-1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(o["part_label"], o["weights"].argmax(-1))
    np.testing.assert_allclose(o["T_cam_obj"], o["part_pose"][:, 0], atol=1e-6)
    for b in range(3):
        rel = o["part_pose"][b, 1] @ np.linalg.inv(o["part_pose"][b, 0])
        ref = joint_motion(0, o["joint_axis"][b, 0].astype(np.float64), o["joint_pivot"][b, 0].astype(np.float64),
                           float(o["joint_state"][b, 0]))
        np.testing.assert_allclose(rel, ref, atol=1e-4)
    # a view's refined answer does not depend on the other views of its batch
    one = pred.predict(pts[1:2])
    np.testing.assert_allclose(one["part_pose"][0], o["part_pose"][1], atol=1e-4)
    preds = run_method("scapo", laptop_data, tmp_path / "p.npz", run=run, refine_steps=3, label="scapo-refined")
    assert preds.method == "scapo-refined" and preds.info["refine_steps"] == 3


def test_training_seed_gives_another_run_and_is_part_of_its_identity(laptop_data, finished_run, tmp_path):
    shutil.copytree(finished_run, tmp_path / "s0")  # trained with seed 0
    train(laptop_data, tmp_path / "s0", TEST, progress=False, seed=0)  # finished with this seed: accepted
    train(laptop_data, tmp_path / "s1", TEST, progress=False, seed=1)
    a = torch.load(tmp_path / "s0" / "checkpoint.pt", weights_only=False)
    b = torch.load(tmp_path / "s1" / "checkpoint.pt", weights_only=False)
    assert a["identity"]["preset"]["seed"] == 0 and b["identity"]["preset"]["seed"] == 1
    assert not torch.equal(a["model"]["y_base"], b["model"]["y_base"])
    with pytest.raises(TrainingError, match="differ: seed"):
        train(laptop_data, tmp_path / "s0", TEST, progress=False, seed=1)
    preds = run_method("scapo", laptop_data, None, run=tmp_path / "s1")
    assert preds.info["seed"] == 1


def test_a_resumed_run_keeps_its_logs_columns(laptop_data, tmp_path):
    """A run started by a scapo whose log had fewer columns resumes into the same columns (a log with rows of two
    widths could not be read back)."""
    import csv

    import pandas as pd

    run = tmp_path / "run"
    interrupt_at(Trainer(laptop_data, run, TEST, progress=False), 2, 0)
    with open(run / "log.csv", newline="") as f:
        rows = list(csv.reader(f))
    old = [r[:-2] for r in rows]  # as written before the supervised columns existed
    with open(run / "log.csv", "w", newline="") as f:
        csv.writer(f).writerows(old)
    Trainer(laptop_data, run, TEST, progress=False).train()
    log = pd.read_csv(run / "log.csv")
    assert list(log.columns) == old[0] and (log["stage"] == 2).any()


def test_set_on_an_existing_run_starts_from_the_runs_own_preset(laptop_data, finished_run, tmp_path):
    """``scapo train --set FIELD=VALUE`` on an existing run without ``--preset`` replaces a field of the run's own
    preset (``--preset``'s help: "default: an existing run's own preset, else cpu"), not of ``cpu``: an interrupted
    run resumes with the change recorded; on a finished run, which is never trained again, it is refused with what to
    do instead."""
    import json

    from scapo.cli.main import main

    p = dataclasses.replace(TEST, stage1_epochs=2, stage2_epochs=1)  # the run's own preset, not the registry's
    run = tmp_path / "run"
    interrupt_at(Trainer(laptop_data, run, p, progress=False), 1, 1)
    assert main(["train", "--data", str(laptop_data), "--out", str(run), "--set", "refine.steps=3",
                 "--no-progress"]) == 0
    ident = json.loads((run / "run.json").read_text())["preset"]
    assert (ident["name"], ident["stage1_epochs"], ident["refine"]["steps"]) == ("test", 2, 3)
    # from cpu (what the command did before the engine resolved the preset once) it would have been another run
    assert main(["train", "--data", str(laptop_data), "--out", str(run), "--preset", "cpu", "--no-progress"]) == 2
    done = tmp_path / "done"
    shutil.copytree(finished_run, done)
    before = (done / "checkpoint.pt").read_bytes()
    with pytest.raises(Exception, match="finished run"):
        from scapo.methods import train_method

        train_method("scapo", laptop_data, done, overrides={"refine.steps": "3"})
    assert (done / "checkpoint.pt").read_bytes() == before


def test_the_lifecycle_resolves_preset_overrides_and_seed_once(tmp_path):
    """:func:`scapo.engine.lifecycle.run_preset`: the given preset, else the run's own (its run.json), else cpu;
    then the overrides; then the seed."""
    import json

    from scapo.engine.lifecycle import run_preset
    from scapo.errors import ConfigError
    from scapo.models.train import SCAPO_RUN

    assert run_preset(SCAPO_RUN, tmp_path / "none").name == "cpu"
    run = tmp_path / "r"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"preset": dataclasses.asdict(TEST)}))
    assert run_preset(SCAPO_RUN, run) == TEST
    pc = run_preset(SCAPO_RUN, run, overrides={"stage1_epochs": "7", "losses.rec": 2.0}, seed=3)
    assert (pc.name, pc.stage1_epochs, pc.losses.rec, pc.seed) == ("test", 7, 2.0, 3)
    assert run_preset(SCAPO_RUN, run, "cpu").name == "cpu"  # a given preset wins over the run's own
    (run / "run.json").write_text(json.dumps({"method": "npcs", "preset": {"epochs": 1}}))
    assert run_preset(SCAPO_RUN, run).name == "cpu"  # another method's run names no SCAPO preset
    for bad in ({"no_such_field": 1}, {"stage1_epochs": "many"}):
        with pytest.raises(ConfigError):
            run_preset(SCAPO_RUN, run, "test", overrides=bad)
    for seed in (-1, 2 ** 32, 1.5):
        with pytest.raises(ConfigError, match="training seed"):
            run_preset(SCAPO_RUN, None, "test", seed=seed)


def test_axis_turn_and_split_fit_are_preset_parts_that_train_and_leave_older_runs_current(laptop_data, tmp_path,
                                                                                             small_part_search,
                                                                                             small_split_choice):
    """``/axis-turn`` starts stage 2's revolute axes from the parts' turns (``TrainConfig.axis_init``) and ``/split-fit``
    chooses its starting split among the keypoint split and fitted template splits (``TrainConfig.split_init``), and
    ``split_labels`` trains stage 2 towards that split's pseudo-labels; the estimators are tested on hand-built clouds in
    tests/test_part_init.py. A run with all three trains and writes the split it chose and its pseudo-labels; at their
    defaults the fields are left out of a run's identity; unknown values and conflicting settings are refused."""
    import json

    from scapo.errors import ConfigError
    from scapo.models.presets import get_preset
    from scapo.models.train import _identity_hash

    p = dataclasses.replace(get_preset("test/axis-turn/split-fit"), part_init=True, split_labels=True,
                            stage2_frame="parts")
    assert p.axis_init == "turn" and get_preset("test").axis_init == "motion"
    assert p.split_init == "fit" and get_preset("test").split_init == "rigid"
    trainer = Trainer(laptop_data, tmp_path / "t", p, progress=False)
    trainer.train()
    # split_labels: every training cloud's pseudo-labels saved for a resume, which reads them back or refuses them
    from scapo.errors import DatasetError
    from scapo.models.train import TrainingClouds

    data = TrainingClouds(laptop_data, 32)
    saved = np.load(tmp_path / "t" / "split_labels.npy", allow_pickle=False)
    assert saved.shape == tuple(data.clouds.shape[:2]) and saved.min() >= 0 and saved.max() < 2
    trainer.job._load_split_labels(data)
    assert torch.equal(data.tensors["part_label"], torch.from_numpy(saved)) and "part_label" in data[0]
    for bad in (b"not a numpy file", None):
        if bad is None:
            np.save(tmp_path / "t" / "split_labels.npy", saved[:, :5])
        else:
            (tmp_path / "t" / "split_labels.npy").write_bytes(bad)
        with pytest.raises(DatasetError, match="split_labels.npy"):
            trainer.job._load_split_labels(TrainingClouds(laptop_data, 32))
    with np.load(tmp_path / "t" / "template_split.npz") as z:  # where the template came from, and its split
        M = trainer.job.mcfg.template_points
        assert 0 <= int(z["sample"]) < len(saved) and z["points"].shape == z["labels"].shape == (M,)
        assert 0 <= z["points"].min() and z["points"].max() < data.clouds.shape[1] and 0 <= z["labels"].min()
        assert len(np.unique(z["points"])) == M and "labels_refit" not in z.files  # split_frame="stage1": no refit
    # stage2_frame="parts": each cloud's target frame (a rotation, or zeros where none) saved, logged, read back or
    # refused
    T = np.load(tmp_path / "t" / "frame_targets.npy", allow_pickle=False)
    has = np.abs(T).sum((1, 2)) > 0
    assert T.shape == (len(saved), 3, 3) and has.any()
    assert np.allclose(T[has] @ T[has].transpose(0, 2, 1), np.eye(3), atol=1e-5)
    assert np.allclose(np.linalg.det(T[has]), 1.0, atol=1e-5)
    info = json.loads((tmp_path / "t" / "frame_target.json").read_text())
    assert info["with_target"] == int(has.sum()) and info["clouds"] == len(saved)
    data = TrainingClouds(laptop_data, 32)
    trainer.job._load_frame_targets(data)
    assert np.allclose(data.tensors["frame_target"].numpy(), T, atol=1e-6) and data[0]["frame_target"].shape == (3, 3)
    np.save(tmp_path / "t" / "frame_targets.npy", T[:3])
    with pytest.raises(DatasetError, match="frame_targets.npy"):
        trainer.job._load_frame_targets(TrainingClouds(laptop_data, 32))
    with pytest.raises(ConfigError, match="set split_labels"):
        dataclasses.replace(p, split_frame="stage1", split_labels=False)
    assert get_preset("cpu/split-fit/split-labels/stage2-parts").stage2_frame == "parts"
    with pytest.raises(ConfigError, match="stage2_frame"):
        dataclasses.replace(p, stage2_frame="nope")
    with pytest.raises(ConfigError, match="set split_labels"):
        dataclasses.replace(p, split_labels=False)
    with pytest.raises(UnknownNameError, match="split-parts"):
        get_preset("cpu/split-fit/split-labels/split-parts")
    with pytest.raises(ConfigError, match="needs part_init"):
        get_preset("test/split-labels")
    with pytest.raises(ConfigError, match="cannot be combined"):
        dataclasses.replace(get_preset("cpu/split-labels"), supervision="S")
    stored = json.loads((tmp_path / "t" / "run.json").read_text())["preset"]
    assert stored["axis_init"] == "turn" and stored["split_init"] == "fit"
    found = json.loads((tmp_path / "t" / "split_init.json").read_text())
    assert found["source"] in ("keypoints", "fit") and found["scores"][found["chosen"]] == min(found["scores"])
    assert sum(found["template_part_points"]) == p.template_points
    ident = {"preset": dataclasses.asdict(get_preset("test")), "dataset_hash": "h", "category": "laptop",
             "part_names": [], "joint_type": [], "joint_parts": []}
    for field in ("axis_init", "split_init", "split_labels", "split_frame", "stage2_frame"):
        older = json.loads(json.dumps(ident))
        del older["preset"][field]  # as written before the field existed
        assert _identity_hash(older) == _identity_hash(ident)
    # switches removed since (REMOVED_FIELDS): a run trained at their off value keeps its identity and loads; one
    # trained with one on is refused, naming the commit that still reads it
    from scapo.models.train import LOSS_REMOVED_FIELDS, REMOVED_AFTER, REMOVED_FIELDS, preset_from_dict

    older = json.loads(json.dumps(ident))
    older["preset"].update(REMOVED_FIELDS)  # as written while the switches existed
    assert _identity_hash(older) == _identity_hash(ident)
    assert preset_from_dict(older["preset"]) == get_preset("test")
    with pytest.raises(ConfigError, match=f"relabel=1, a switch removed after {REMOVED_AFTER}"):
        preset_from_dict({**older["preset"], "relabel": 1})
    with pytest.raises(ConfigError, match="split_frame='parts', a setting removed"):
        preset_from_dict({**older["preset"], "split_frame": "parts"})
    older["preset"]["losses"].update(LOSS_REMOVED_FIELDS)
    assert _identity_hash(older) == _identity_hash(ident) and preset_from_dict(older["preset"]) == get_preset("test")
    with pytest.raises(ConfigError, match="losses.view_consist=1.0"):
        preset_from_dict({**older["preset"], "losses": {**older["preset"]["losses"], "view_consist": 1.0}})
    with pytest.raises(UnknownNameError, match="frame-target"):
        get_preset("cpu/split-fit/split-labels/frame-target")
    assert _identity_hash({**ident, "preset": dataclasses.asdict(p)}) != _identity_hash(ident)
    for field in ("axis_init", "split_init", "split_frame"):
        with pytest.raises(ConfigError, match=field):
            dataclasses.replace(TEST, **{field: "nope"})


def test_frame_targets_give_one_frame_where_the_stage1_frames_take_half_turned_branches(tmp_path):
    """Hand-built glasses (a front bar, two temples behind it) seen under random rotations; the "stage-1 frames" are
    the true frames turned by a half turn about the front's normal in a random half of the clouds (the branch a
    near-symmetric front leaves open). The targets ``R_i E_i E_Y^T`` are the true frames up to one fixed rotation."""
    import types

    from scapo.models.train import ScapoJob
    from scapo.ops.so3 import exp_so3

    g = torch.Generator().manual_seed(0)
    front = torch.rand(200, 3, generator=g) * torch.tensor([1.0, 0.3, 0.05]) - torch.tensor([0.5, 0.15, 0.0])
    left = torch.rand(80, 3, generator=g) * torch.tensor([0.03, 0.03, 0.6]) + torch.tensor([-0.5, 0.0, 0.02])
    right = torch.rand(80, 3, generator=g) * torch.tensor([0.03, 0.03, 0.6]) + torch.tensor([0.47, 0.0, 0.02])
    obj = torch.cat([front, left, right])
    lab = torch.cat([torch.zeros(200), torch.ones(80), torch.full((80,), 2)]).long()
    B = 24
    true = exp_so3(torch.nn.functional.normalize(torch.randn(B, 3, generator=g), dim=-1),
                   torch.rand(B, generator=g) * 3.0)
    half = exp_so3(torch.tensor([[0.0, 0.0, 1.0]]).expand(B, 3), torch.full((B,), torch.pi))
    flip = torch.arange(B) % 2 == 1
    branch = torch.where(flip[:, None, None], half, torch.eye(3).expand(B, 3, 3))
    frames = true @ branch  # canonical -> camera, half of them half-turned
    cam = obj[None] @ true.transpose(1, 2)
    canon = cam @ frames  # each cloud in its own stage-1 frame
    job = types.SimpleNamespace(dist=types.SimpleNamespace(is_main=True), run=tmp_path,
                                preset=types.SimpleNamespace(parts_axes="pca"))
    T, pair, tpl = ScapoJob._frame_targets(job, obj, lab, canon, frames, lab.expand(B, -1))
    assert len(pair) == 2 and torch.allclose(tpl @ tpl.T, torch.eye(3), atol=1e-5)
    offset = true.transpose(1, 2) @ T  # the same rotation for every cloud
    assert torch.allclose(offset, offset[0].expand(B, 3, 3), atol=1e-4)
    info = __import__("json").loads((tmp_path / "frame_target.json").read_text())
    assert info["with_target"] == B and info["beyond_90_deg"] == 0.5


def _check_stage2_starts(model, X: torch.Tensor, plain) -> None:
    """``SCAPOModel.passes(X, starts)`` (``RefineConfig.stage2_starts``) on a model trained with stage 2 in the
    parts-signed frame: each cloud keeps the outputs of the start whose posed template lies nearest its points."""
    from scapo.models.branch import apply_branch
    from scapo.models.scapo_model import stage2_start_rotations
    from scapo.ops.chamfer import nearest_sq_dist

    G = stage2_start_rotations("D2")
    assert torch.equal(G[0], torch.eye(3)) and torch.allclose(G @ G.transpose(1, 2), torch.eye(3).expand(4, 3, 3))
    assert torch.equal(model.passes(X, "off").w, plain.w)  # "off": the stage-1 frame alone
    # the real outputs: the choice is the start of least one-sided Chamfer distance, cloud by cloud
    s1 = model.stage1(X)
    R0 = apply_branch(s1.enc.R, model.branch, model.branch_flip)
    each = [model._passes_from(X, s1, R0 @ g) for g in G]
    assert torch.equal(each[0].w, plain.w)  # the identity start is the plain prediction
    best = torch.stack([nearest_sq_dist(o.S_obj, o.S_y2x).mean(-1) for o in each]).argmin(0)
    chosen = model.passes(X, "D2")
    for b, k in enumerate(best.tolist()):
        assert torch.equal(chosen.w[b], each[k].w[b]) and torch.equal(chosen.R[b], each[k].R[b])
        assert torch.equal(chosen.T_x[b], each[k].T_x[b]) and torch.equal(chosen.S_y2x[b], each[k].S_y2x[b])
    # a hand-built case: start k's posed template is cloud b's points shifted by off[b, k] (distance off^2); a
    # marker of the start in w
    off = torch.tensor([[0.3, 0.1, 0.2, 0.3], [0.2, 0.4, 0.4, 0.4], [0.3, 0.2, 0.1, 0.2], [0.5, 0.5, 0.5, 0.5]])
    calls = []

    def fake(X_, s1_, frame=None):
        k = len(calls)
        calls.append(frame)
        o = each[0]
        return dataclasses.replace(o, S_y2x=o.S_obj + off[:, k, None, None], w=torch.full_like(o.w, float(k)))

    model._passes_from = fake
    try:
        picked = model.passes(X, "D2").w[:, 0, 0].long().tolist()
    finally:
        del model._passes_from
    assert picked == [1, 0, 2, 0]  # the nearest start; the tie in cloud 3 (all 0.5) keeps the first
    assert len(calls) == 4 and all(torch.allclose(f, R0 @ g) for f, g in zip(calls, G))
    with pytest.raises(ValueError, match="stage2_starts"):
        model.passes(X, "D3")
    for name in ("", "off"):
        with pytest.raises(ValueError, match="stage2_starts"):
            stage2_start_rotations(name)


def test_stage2_parts_frame_trains_in_the_targets_and_predicts_in_the_frame_its_base_gives(laptop_data, tmp_path,
                                                                                             small_part_search,
                                                                                             small_split_choice):
    """``stage2_frame="parts"``: the run stores the template's signed base axes (a rotation) and ranks in the model,
    stage 2 uses a cloud's given frame in place of its stage-1 one (zeros: its own), and prediction runs stage 2 again
    in the frame read from the base it labels (:meth:`SCAPOModel.parts_frames`), which a model without the buffers
    (older checkpoints) skips."""
    import json

    from scapo.errors import ConfigError
    from scapo.models.presets import get_preset
    from scapo.models.scapo_model import PARTS_PASSES, SCAPOModel
    from scapo.models.train import TrainingClouds

    p = dataclasses.replace(get_preset("test/axis-turn/split-fit"), part_init=True, split_labels=True,
                            stage2_frame="parts", split_frame="refit", axis_init="sweep")
    trainer = Trainer(laptop_data, tmp_path / "t", p, progress=False)
    trainer.train()
    model = trainer.model
    swept = json.loads((tmp_path / "t" / "axis_sweep.json").read_text())["joints"]  # axis_init="sweep"
    assert len(swept) == 1 and swept[0]["mode"] in ("sweep", "still", "kept")
    if swept[0]["mode"] != "kept":
        assert np.isclose(np.linalg.norm(swept[0]["axis"]), 1.0, atol=1e-3) and swept[0]["views"] >= 8
    with pytest.raises(ConfigError, match="axis_init='sweep'"):
        dataclasses.replace(p, stage2_frame="stage1", split_frame="stage1")
    assert get_preset("cpu/split-fit/split-labels/stage2-parts/axis-sweep").axis_init == "sweep"
    E = model.parts_frame
    assert model.uses_parts_frame and torch.allclose(E @ E.T, torch.eye(3), atol=1e-5)
    assert (tmp_path / "t" / "frame_targets.npy").is_file()
    labels = np.load(tmp_path / "t" / "split_labels.npy", allow_pickle=False)  # split_frame="refit": labelled again
    assert labels.shape[0] == len(np.load(tmp_path / "t" / "frame_targets.npy")) and labels.max() < 2
    assert labels.shape == tuple(TrainingClouds(laptop_data, 64).clouds.shape[:2])  # every point labelled
    refit = json.loads((tmp_path / "t" / "split_refit.json").read_text())
    assert sum(refit["template_part_points"]) == p.template_points and 0 <= refit["labels_changed"] <= 1
    assert get_preset("cpu/split-fit/split-labels/stage2-parts/split-refit").split_frame == "refit"
    assert get_preset("cpu/split-fit/split-labels/stage2-parts/parts-plane").parts_axes == "plane"
    assert model.parts_axes == "pca"
    with pytest.raises(ConfigError, match="stage2_frame"):
        dataclasses.replace(p, stage2_frame="stage1")
    with pytest.raises(ConfigError, match="parts_axes"):
        dataclasses.replace(p, parts_axes="ransac")
    pts = TrainingClouds(laptop_data, 64).clouds[:4, :64]
    X, _ = model.normalize(pts)
    model.eval()
    with torch.no_grad():
        own = model(X, stage=2)
        turned = torch.linalg.qr(torch.randn(3, 3, generator=torch.Generator().manual_seed(1)))[0]
        turned = turned * torch.sign(torch.linalg.det(turned))
        given = torch.zeros(4, 3, 3)
        given[0] = turned
        mixed = model(X, stage=2, frame=given)
        assert torch.allclose(mixed.R[0], turned) and torch.allclose(mixed.R[1:], own.R[1:])
        F = model.parts_frames(X, own.w.argmax(-1))
        out = model.predict(pts)
        looped = own  # passes() runs stage 1 once; the same outputs as one forward() per pass
        for _ in range(PARTS_PASSES):
            looped = model(X, stage=2, frame=model.parts_frames(X, looped.w.argmax(-1)))
        shared = model.passes(X)
        assert PARTS_PASSES > 0 and torch.equal(shared.w, looped.w) and torch.equal(shared.R, looped.R)
        assert torch.equal(shared.T_x, looped.T_x) and torch.equal(shared.Y_star, looped.Y_star)
        _check_stage2_starts(model, X, shared)
        model.parts_plane.fill_(1)  # parts_axes="plane": the base's directions from its points on its plane
        F_plane = model.parts_frames(X, own.w.argmax(-1))
        model.parts_plane.fill_(0)
    found_plane = F_plane.flatten(1).abs().sum(-1) > 0
    assert model.parts_axes == "pca" and torch.equal(found_plane, F.flatten(1).abs().sum(-1) > 0)
    found = F.flatten(1).abs().sum(-1) > 0
    R = out["T_cam_obj"][:, :3, :3]
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3).expand(4, 3, 3), atol=1e-4)
    if bool(found.any()):  # the frames read from the base: rotations E_i E_Y^T
        assert torch.allclose(F[found] @ F[found].transpose(1, 2), torch.eye(3).expand(int(found.sum()), 3, 3),
                              atol=1e-4)
    # bench/diagnostics/parts_frame.py: the ground-truth diagnosis of such a run, pass by pass and on its training targets
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("parts_frame", Path(__file__).resolve().parents[1] / "bench" /
                                                  "diagnostics" / "parts_frame.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--data", str(laptop_data), "--run", f"r={tmp_path / 't'}", "--passes", "2", "--split", "test",
                       "--out", str(tmp_path / "pf")]) == 0
    diag = json.loads((tmp_path / "pf.json").read_text())["rows"]["r"]
    assert [r["pass"] for r in diag["val"]] == [0, 1, 2, "true labels"]
    assert all(0.0 <= r["frame"] <= 1.0 for r in diag["val"]) and diag["train"]["clouds"] == len(labels)
    assert "mirror_exchanged_in" not in diag["train"]  # a laptop's base has one child
    states = diag["train"]["by_state"]  # by quartile of the lid's joint state: every training cloud in one bin
    assert len(states) == 4 and sum(b["samples"] for b in states) == len(labels)
    assert all(b["state_from"] <= b["state_to"] for b in states) and diag["val"][-2]["by_state"] is not None
    assert bench.main(["--data", str(laptop_data), "--run", "no-label", "--out", str(tmp_path / "pf2")]) == 2
    state = {k: v for k, v in model.state_dict().items()
             if k not in ("parts_frame", "parts_pair", "parts_plane", "joints.axis_frozen")}
    older = SCAPOModel(model.cfg)
    older.load_checkpoint_state(state)  # a checkpoint from before the parts frame: off
    assert not older.uses_parts_frame and older.parts_axes == "pca" and not older.joints.axis_frozen.any()


def test_a_frozen_joint_axis_stays_at_its_bias_while_the_rest_of_the_head_trains():
    """``TrainConfig.axis_fixed``: after :meth:`JointHead.freeze_axis` the frozen joint's axis is its bias direction
    for every shape and does not move under optimisation; the other joint's axis and every pivot still train; a
    checkpoint from before the flag loads with no axis frozen; ``axis_fixed`` needs ``axis_init="sweep"``."""
    from scapo.errors import ConfigError
    from scapo.models.presets import get_preset
    from scapo.models.scapo_model import JointHead

    torch.manual_seed(0)
    head = JointHead(2, (16, 32))
    head.freeze_axis(0)
    bias0 = head.joint_bias()[0, 3:6].detach().clone()
    opt = torch.optim.AdamW(head.parameters(), lr=1e-2, weight_decay=0.0)
    shapes = torch.randn(4, 50, 3)
    before = head(shapes)
    for _ in range(5):
        opt.zero_grad()
        pivot, axis, state, _ = head(shapes)
        (pivot.square().sum() + (axis - torch.tensor([1.0, 0.0, 0.0])).square().sum() + state.square().sum()).backward()
        opt.step()
    after = head(torch.randn(3, 50, 3))
    assert torch.allclose(after[1][:, 0], (bias0 / bias0.norm()).expand(3, 3), atol=1e-6)
    assert torch.equal(head.joint_bias()[0, 3:6], bias0)
    assert not torch.allclose(before[1][:, 1], head(shapes)[1][:, 1]) and not torch.allclose(before[0], head(shapes)[0])
    with pytest.raises(ConfigError, match="axis_fixed"):
        dataclasses.replace(get_preset("cpu"), axis_fixed=True)
    assert get_preset("cpu/split-fit/split-labels/stage2-parts/axis-sweep/axis-fixed").axis_fixed
