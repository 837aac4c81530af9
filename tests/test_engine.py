"""The training engine (scapo.engine): one loop for every trained method, pinned against the loops it replaced,
and open to a new method defined outside the package (a toy learned method trains, predicts and is scored through
the CLI with no edit anywhere else)."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import engine_pins  # tests/engine_pins.py (pytest puts tests/ on sys.path)
import numpy as np
import pytest
import torch
from torch.utils.data.distributed import DistributedSampler

from scapo.engine import CloudSet, FitConfig, RunFolder
from scapo.engine.distributed import DistContext
from scapo.engine.loop import epoch_batches
from scapo.errors import ConfigError, TrainingError
from scapo.methods import METHODS, train_method

DATA = Path(__file__).parent / "data"
PINS = engine_pins.load_pins()


@pytest.mark.parametrize("key", engine_pins.pinned_keys(PINS))
def test_every_methods_test_preset_gives_the_losses_of_the_loops_before_the_engine(key, tmp_path):
    """``engine_pins.json`` holds the log of each trained method's ``test`` preset (and ``test/sj``) trained by the
    two loops the engine replaced (commit c217f4f) on ``tests/data/pin_laptop``, on each CPU it was pinned on; a
    method whose losses changed by design since is re-pinned (``repinned`` says why), and a CPU kind met later is
    pinned with today's engine (``tests/engine_pins.py --add``). Every loss of every step is a pinned CPU's at 1e-6
    relative (far below what a different batch order or seed changes). Pins of one CPU do not hold on another: an
    AMD EPYC's rounding moves op-align's small terms by up to 1e-4 and flips a discrete choice of SCAPO's stage-2
    initialisation. On a CPU that is not pinned, the first stage must agree with a pinned CPU to 1e-3 and the later
    rows be complete and finite (a warning says so); a pinned CPU gets no such leeway (``engine_pins.verdict``)."""
    rows = engine_pins.train_log(key, tmp_path / "run")
    ok, msg = engine_pins.verdict(rows, key, PINS, engine_pins.cpu_id())
    assert ok, msg
    if msg:
        warnings.warn(msg, stacklevel=1)


def _log(*rows: list) -> list[list[str]]:
    return [["stage", "epoch", "step", "lr", "total"]] + [[str(v) for v in r] for r in rows]


def test_the_pin_verdict_is_bit_level_on_a_pinned_cpu_and_bounded_on_another():
    pin = _log([1, 0, 0, 1e-3, 2.0], [1, 0, 1, 1e-3, 1.5], [2, 0, 0, 1e-3, 0.8], [2, 0, 1, 1e-3, 0.7])
    pins = {"cpu": "A", "cpu_id": "cpu-a", "runs": {"m:test": {"header": pin[0], "rows": pin[1:]}}}
    same = _log([1, 0, 0, 1e-3, 2.0], [1, 0, 1, 1e-3, 1.5], [2, 0, 0, 1e-3, 0.8], [2, 0, 1, 1e-3, 0.7])
    rounding = _log([1, 0, 0, 1e-3, 2.0004], [1, 0, 1, 1e-3, 1.5], [2, 0, 0, 1e-3, 1.9], [2, 0, 1, 1e-3, 0.1])
    assert engine_pins.verdict(same, "m:test", pins, "cpu-a") == (True, "")
    assert engine_pins.verdict(same, "m:test", pins, "cpu-b") == (True, "")
    ok, msg = engine_pins.verdict(rounding, "m:test", pins, "cpu-a")  # a pinned CPU gets no leeway
    assert not ok and "is pinned as 'A'" in msg
    ok, msg = engine_pins.verdict(rounding, "m:test", pins, "cpu-b")  # 2e-4 in stage 1, stage 2 free but finite
    assert ok and "not pinned" in msg
    changed = _log([1, 0, 0, 1e-3, 2.02], [1, 0, 1, 1e-3, 1.5], [2, 0, 0, 1e-3, 0.8], [2, 0, 1, 1e-3, 0.7])
    ok, msg = engine_pins.verdict(changed, "m:test", pins, "cpu-b")  # 1 % in stage 1: the losses changed
    assert not ok and "not even the first stage" in msg
    nan = _log([1, 0, 0, 1e-3, 2.0], [1, 0, 1, 1e-3, 1.5], [2, 0, 0, 1e-3, "nan"], [2, 0, 1, 1e-3, 0.7])
    ok, msg = engine_pins.verdict(nan, "m:test", pins, "cpu-b")
    assert not ok and "not finite" in msg
    short = _log([1, 0, 0, 1e-3, 2.0], [1, 0, 1, 1e-3, 1.5], [2, 0, 0, 1e-3, 0.8])
    assert not engine_pins.verdict(short, "m:test", pins, "cpu-b")[0]
    skipped = _log([1, 0, 0, 1e-3, 2.0], [1, 0, 1, 1e-3, 1.5], [2, 0, 0, 1e-3, 0.8], [2, 1, 0, 1e-3, 0.7])
    ok, msg = engine_pins.verdict(skipped, "m:test", pins, "cpu-b")
    assert not ok and "row ['2', '0', '1'] is ['2', '1', '0']" in msg
    assert engine_pins.cpu_id().count(";") == 1 or engine_pins.cpu_id() == "unknown"


def test_the_permutation_order_is_distributed_samplers_and_shards_it_among_ranks():
    data = CloudSet({"points": torch.randn(10, 32, 3), "part_label": torch.arange(32).repeat(10, 1)}, points=8)
    cfg = FitConfig(batch_size=2, seed=3, order="permutation")
    one = [b for b in epoch_batches(data, cfg, 77, DistContext())]
    assert len(one) == 5 and all(b["points"].shape == (2, 8, 3) for b in one)
    perm = list(DistributedSampler(range(10), num_replicas=1, rank=0, shuffle=True, seed=77, drop_last=True))
    got = [int(torch.nonzero((data.clouds == b["points"][i, 0]).all(-1))[0, 0]) for b in one for i in range(2)]
    assert got == perm
    # the per-point fields keep the same subset as the points
    b = one[0]
    i = perm[0]
    np.testing.assert_array_equal(b["points"][0].numpy(), data.clouds[i, b["part_label"][0].long()].numpy())
    # two ranks: each its share of the same permutation (an incomplete last batch is dropped)
    shares = [[int(torch.nonzero((data.clouds == bb["points"][k, 0]).all(-1))[0, 0]) for bb in
               epoch_batches(data, cfg, 77, DistContext(rank=r, world=2)) for k in range(len(bb["points"]))]
              for r in (0, 1)]
    assert shares[0] == perm[0::2][:4] and shares[1] == perm[1::2][:4]  # 5 each, two full batches of 2


def test_a_run_folder_refuses_files_foreign_folders_and_other_identities(tmp_path):
    ident = {"method": "toy", "preset": {"name": "a", "seed": 0}, "dataset_hash": "x" * 64, "category": "laptop"}
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match="existing file"):
        RunFolder(tmp_path / "file", ident).check_target()
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("x")
    with pytest.raises(ConfigError, match="non-empty folder without a scapo run"):
        RunFolder(tmp_path / "foreign", ident).check_target()
    run = RunFolder(tmp_path / "run", ident)
    (tmp_path / "run").mkdir()  # train_run makes it (check_output_dir)
    run.write_identity()
    assert run.is_current() and run.load_checkpoint() is None
    other = RunFolder(tmp_path / "run", {**ident, "preset": {"name": "a", "seed": 1}})
    with pytest.raises(TrainingError, match=r"'toy' run started with preset 'a'.*differ: seed"):
        other.load_checkpoint()
    run.save({"model": {}, "epoch": 1})
    with pytest.raises(TrainingError, match="'toy' run trained with preset 'a'"):
        other.load_checkpoint()
    # a normalisation that leaves the seed out makes the two the same run
    assert RunFolder(tmp_path / "run", other.identity, lambda d: {**d, "preset": {"name": "a"}}).load_checkpoint()
    (tmp_path / "run" / "checkpoint.pt").write_bytes(b"garbage")
    with pytest.raises(TrainingError, match="cannot be read"):
        run.load_checkpoint()


# ---------------------------------------------------------------------------------------------- a toy method
def _toy_preset(name: str):
    """A toy method's preset: the fields every learned preset has (scapo.methods.learned.LearnedPreset)."""
    from scapo.methods.learned import LearnedPreset

    return LearnedPreset(name=name, epochs=2, batch_size=4, lr=1e-2, min_lr=1e-4, weight_decay=0.0, points=64,
                         max_steps_per_epoch=2, device="cpu")


class ToyNet(torch.nn.Module):
    """Predicts each part as the whole cloud, posed at the cloud's centroid plus a learned offset."""

    def __init__(self, card: dict, preset):
        super().__init__()
        self.parts = len(card["part_names"])
        self.joints = len(card["joint_type"])
        self.offset = torch.nn.Parameter(torch.zeros(3))

    def losses(self, batch: dict, progress: float):
        pts = batch["points"]
        err = ((pts.mean(1) + self.offset - pts.mean(1).detach()) ** 2).sum(-1).mean()
        return {"centre": err}, err

    def infer(self, points: torch.Tensor) -> dict:
        B, N, _ = points.shape
        pose = torch.eye(4).repeat(B, self.parts, 1, 1)
        pose[:, :, :3, 3] = (points.mean(1) + self.offset)[:, None]
        T = pose[:, 0].clone()
        axis = torch.tensor([0.0, 0.0, 1.0]).repeat(B, self.joints, 1)
        return {"part_label": np.zeros((B, N), np.int64), "part_pose": pose.detach().numpy(),
                "joint_axis": axis.numpy(), "joint_pivot": pose[:, :self.joints, :3, 3].detach().numpy(),
                "joint_state": np.zeros((B, self.joints)), "T_cam_obj": T.detach().numpy()}


@pytest.fixture
def toy_method():
    from scapo.methods.learned import LearnedSpec, register_learned
    from scapo.registry import Registry

    presets = Registry("toy preset")
    presets.add("test", _toy_preset("test"))
    presets.add("cpu", _toy_preset("cpu"))
    spec = LearnedSpec(method="toy", presets=presets, fields=("points",), build=ToyNet)
    register_learned(spec, display="Toy-style", supervision={"pose": False, "segmentation": False, "joint": False},
                     needs_alignment=True, summary="a toy method defined in a test")
    yield "toy"
    METHODS.remove("toy")


def test_a_method_defined_outside_the_package_trains_predicts_and_is_scored_through_the_cli(
        toy_method, laptop_data, tmp_path, capsys):
    from scapo.cli.main import main

    run, pred = tmp_path / "run", tmp_path / "p.npz"
    assert main(["train", "--method", toy_method, "--data", str(laptop_data), "--preset", "test", "--out", str(run),
                 "--no-progress"]) == 0
    with open(run / "log.csv", newline="") as f:
        log = list(csv.DictReader(f))
    assert list(log[0]) == ["stage", "epoch", "step", "lr", "total", "centre"] and len(log) == 4  # 2 epochs x 2 steps
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    assert state["done"] and state["identity"]["method"] == "toy"
    assert main(["predict", "--run", str(run), "--data", str(laptop_data), "--out", str(pred)]) == 0
    assert main(["evaluate", "--data", str(laptop_data), "--pred", str(pred), "--out", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    assert "Toy-style" in out
    assert "toy" not in METHODS.names() or METHODS.get("toy").trained


def test_the_loss_plot_is_drawn_at_most_once_a_minute_at_the_end_and_at_a_failure(toy_method, laptop_data,
                                                                                  tmp_path, monkeypatch):
    """``losses.png`` costs about a second of CPU per drawing: a short run draws it once (after its last epoch),
    a run whose epochs each pass ``PLOT_EVERY_S`` draws it after every epoch, and a run stopped by a NaN loss
    draws what it logged before the failure."""
    from scapo.engine import loop

    drawn = []
    real = loop.plot_losses
    monkeypatch.setattr(loop, "plot_losses", lambda log, png: (drawn.append(len(log.read_text().splitlines())),
                                                               real(log, png)))
    train_method(toy_method, laptop_data, tmp_path / "short", "test", progress=False)
    assert drawn == [5] and (tmp_path / "short" / "losses.png").is_file()  # header + 2 epochs x 2 steps
    drawn.clear()
    monkeypatch.setattr(loop, "PLOT_EVERY_S", 0.0)
    train_method(toy_method, laptop_data, tmp_path / "every", "test", progress=False)
    assert drawn == [3, 5]
    drawn.clear()
    monkeypatch.setattr(loop, "PLOT_EVERY_S", 60.0)
    def nan_in_the_second_epoch(self, batch, progress):
        err = self.offset.sum() * (float("nan") if progress >= 0.5 else 1.0)
        return {"centre": err}, err

    monkeypatch.setattr(ToyNet, "losses", nan_in_the_second_epoch)
    with pytest.raises(TrainingError, match="loss 'centre' became nan"):
        train_method(toy_method, laptop_data, tmp_path / "nan", "test", progress=False)
    assert drawn == [3] and (tmp_path / "nan" / "losses.png").is_file()  # the first epoch's rows
    drawn.clear()
    monkeypatch.setattr(ToyNet, "losses", lambda self, batch, progress: ({"centre": self.offset.sum() * float("nan")},
                                                                         self.offset.sum() * float("nan")))
    with pytest.raises(TrainingError, match="loss 'centre' became nan"):  # at the first step: nothing to draw
        train_method(toy_method, laptop_data, tmp_path / "nan0", "test", progress=False)
    assert not (tmp_path / "nan0" / "losses.png").exists()


def test_a_step_schedule_halves_the_rate_every_decay_steps_and_iterations_set_the_epochs(laptop_data):
    """OP-Align's schedule (lr halved every 5,000 iterations, 20,000 iterations) as a preset can state it: the
    engine's step schedule and a learned preset's ``iterations``."""
    import dataclasses

    from scapo.data import load
    from scapo.engine.loop import Stage
    from scapo.errors import ConfigError
    from scapo.methods import op_align
    from scapo.methods.learned import learned_job

    p = torch.nn.Parameter(torch.zeros(1))
    stage = Stage(index=1, epochs=1, lr=1.0, params=lambda: [p], losses=None, schedule="step", decay=0.5,
                  decay_steps=3)
    opt = torch.optim.SGD([p], lr=1.0)
    sched = stage.scheduler(opt, steps=100, min_lr=0.0)
    rates = []
    for _ in range(7):
        rates.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert rates == [1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.25]
    with pytest.raises(ValueError, match="schedule"):
        Stage(index=1, epochs=1, lr=1.0, params=lambda: [], losses=None, schedule="linear")
    pc = dataclasses.replace(op_align.PRESETS.get("test"), iterations=7, lr_schedule="step", lr_decay_steps=2,
                             max_steps_per_epoch=0, batch_size=4)
    train = load(laptop_data, split="train")
    job = learned_job(op_align.SPEC, pc, train, torch.device("cpu"))
    per_epoch = job.steps_per_epoch(1)
    assert job.stages[0].epochs == -(-7 // per_epoch) and job.stages[0].schedule == "step"
    assert op_align.PRESETS.get("paper").iterations == 20000 and op_align.PRESETS.get("paper").lr == 1e-4
    with pytest.raises(ConfigError, match="lr_schedule"):
        dataclasses.replace(pc, lr_schedule="linear")


def test_training_takes_the_usable_cores_at_most_omp_num_threads(monkeypatch, tmp_path):
    """Training runs ``min(usable cores, OMP_NUM_THREADS)`` torch threads; an unset, empty, malformed or
    non-positive ``OMP_NUM_THREADS`` leaves the usable cores."""
    import scapo.provenance as prov
    from scapo.engine import loop

    monkeypatch.setattr(prov, "usable_cores", lambda: 4)
    for value, want in (("1", 1), ("3", 3), ("16", 4), ("", 4), ("two", 4), ("0", 4), ("-2", 4), (" 2 ", 2)):
        monkeypatch.setenv("OMP_NUM_THREADS", value)
        assert prov.training_threads() == want, value
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert prov.training_threads() == 4
    seen = []
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.setattr(loop, "fit", lambda *a, **k: seen.append(torch.get_num_threads()))
    train_method("npcs", DATA / "pin_laptop", tmp_path / "run", "test", progress=False)
    assert seen == [1]


def test_nan_weights_stop_training_with_the_tensor_named():
    """An optimiser step can make weights NaN or infinite while every loss it saw was finite (an extreme learning
    rate at the last step of an epoch); the engine checks the weights before each checkpoint."""
    import torch

    from scapo.engine.loop import _check_weights
    from scapo.errors import TrainingError

    net = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
    _check_weights(net, 1, 0)  # finite: nothing said
    with torch.no_grad():
        net[1].bias[0] = float("inf")
    with pytest.raises(TrainingError, match=r"1 weight tensor\(s\) became NaN or infinite in stage 2, epoch 3 "
                                            r"\(first: 1.bias\)"):
        _check_weights(net, 2, 3)


def test_a_corrected_rerun_starts_over_after_a_run_that_failed_before_its_first_checkpoint(tmp_path):
    """A run refused in its first epoch (a NaN loss, a full disk) leaves its identity and the record of its failure:
    the corrected run, of another preset, starts over in the folder; a run merely interrupted there stays protected
    (``test_bad_input.py``)."""
    import torch

    from scapo.engine import CloudSet, FitConfig, RunFolder, Stage, TrainJob, train_run
    from scapo.errors import TrainingError

    def job(lr):
        net = torch.nn.Linear(3, 3)
        data = CloudSet({"points": torch.randn(8, 16, 3)}, 16)

        def losses(batch, progress):
            out = net(batch["points"]).pow(2).mean()
            return {"fit": out * (float("nan") if lr > 1 else 1.0)}, out

        return TrainJob(model=net, data=data, stages=[Stage(index=1, epochs=1, lr=lr, params=lambda: list(
            net.parameters()), losses=losses, terms=("fit",))], config=FitConfig(batch_size=4))

    run = tmp_path / "run"
    bad = RunFolder(run, {"method": "toy", "preset": {"name": "a", "lr": 10.0}})
    with pytest.raises(TrainingError, match="became nan"):
        train_run(bad, lambda dev, ctx: job(10.0), torch.device("cpu"), progress=False)
    assert (run / "failed.json").is_file() and not (run / "checkpoint.pt").exists()
    good = RunFolder(run, {"method": "toy", "preset": {"name": "a", "lr": 0.01}})
    assert train_run(good, lambda dev, ctx: job(0.01), torch.device("cpu"), progress=False).is_file()
    assert not (run / "failed.json").exists() and good.is_current()


# ---------------------------------------------------------------------------------------------- compiled steps
def _compile_job(compile_: bool):
    """Two stages of a small network with batch norm and dropout (torch's RNG inside the compiled part) and a noisy
    loss (outside it), on clouds subsampled per step."""
    from scapo.engine import Stage, TrainJob

    torch.manual_seed(0)
    net = torch.nn.Module()
    net.body = torch.nn.Sequential(torch.nn.Linear(3, 16, bias=False), torch.nn.BatchNorm1d(16), torch.nn.ReLU(),
                                   torch.nn.Dropout(0.2), torch.nn.Linear(16, 3))  # random inside the compiled part
    data = CloudSet({"points": torch.randn(24, 40, 3, generator=torch.Generator().manual_seed(1))}, 32)

    def losses(batch, progress):
        x = batch["points"]
        y = net.body(x.reshape(-1, 3)).reshape(x.shape)
        fit = (y - x.flip(-1) + 0.1 * torch.randn_like(x)).pow(2).mean()
        return {"fit": fit}, fit

    stages = [Stage(index=k, epochs=2, lr=1e-2 / k, params=lambda: list(net.parameters()), losses=losses,
                    terms=("fit",)) for k in (1, 2)]
    return TrainJob(model=net, data=data, stages=stages, config=FitConfig(batch_size=8, seed=3, compile=compile_))


def _train_toy(run: Path, compile_: bool) -> tuple[list[float], dict]:
    import json

    from scapo.engine import RunFolder, train_run

    folder = RunFolder(run, {"method": "toy", "preset": {"name": "c", "compile": compile_}})
    ckpt = train_run(folder, lambda dev, ctx: _compile_job(compile_), torch.device("cpu"), progress=False)
    with open(run / "log.csv", newline="") as f:
        totals = [float(r["total"]) for r in csv.DictReader(f)]
    timing = json.loads((run / "timing.json").read_text())
    for k in ("1", "2"):  # each epoch's CPU seconds of steps: whether a step's cost drifts over a run
        per_epoch = timing["stages"][k]["epoch_step_cpu_s"]
        assert len(per_epoch) == 2 and all(v >= 0 for v in per_epoch)
        assert sum(per_epoch) <= timing["ledger"]["phases"][f"stage{k}/steps"]["cpu_s"] + 0.05
    return totals, {"ledger": timing["ledger"], "state": torch.load(ckpt, weights_only=False)["model"]}


def test_a_compiled_run_trains_the_same_losses_and_charges_its_compilation(tmp_path):
    """``FitConfig.compile``: the same losses step by step as the eager run (float32 kernels fused differently:
    within 1e-4 relative), the same state-dict keys, each stage's compilation in its own ledger phase (one-time
    work: :func:`scapo.engine.ledger.one_time_s`), the dropout inside the compiled part draws torch's random numbers
    as the eager step does, and the warm-up leaves the batch-norm statistics and random generators alone (the first
    step's loss, which reads them, agrees)."""
    from scapo.engine.ledger import one_time_s

    eager, e = _train_toy(tmp_path / "eager", False)
    fast, c = _train_toy(tmp_path / "compiled", True)
    assert len(eager) == len(fast) == 12
    np.testing.assert_allclose(fast, eager, rtol=1e-4)
    assert list(c["state"]) == list(e["state"])
    for k in e["state"]:
        torch.testing.assert_close(c["state"][k], e["state"][k], rtol=1e-3, atol=1e-5)
    phases = c["ledger"]["phases"]
    assert {"stage1/compile", "stage2/compile"} <= set(phases) and "stage1/compile" not in e["ledger"]["phases"]
    assert one_time_s(c["ledger"]) >= phases["stage1/compile"]["charged_s"] > 0  # tracing (code from the disk cache)


def test_a_failed_compilation_warns_and_trains_eagerly_with_the_same_losses(tmp_path, monkeypatch):
    """Where ``torch.compile`` fails (no compiler, an unsupported operation), the run warns once per stage and trains
    eagerly: bit for bit the eager run."""
    def broken(fn, *args, **kwargs):
        def fail(*a, **k):
            raise RuntimeError("no C++ compiler found")
        return fail

    monkeypatch.setattr(torch, "compile", broken)
    eager, _ = _train_toy(tmp_path / "eager", False)
    with pytest.warns(RuntimeWarning, match=r"scapo: torch.compile failed for stage 1 \(RuntimeError: no C\+\+ "
                                            r"compiler found\); training eagerly"):
        fast, _ = _train_toy(tmp_path / "fallback", True)
    assert fast == eager


def test_step_seconds_times_the_eager_and_the_compiled_step_and_leaves_the_network_eager():
    """``scapo.engine.speed.step_seconds`` (``bench perf --what train`` of a compiling preset): the eager step, the
    compiled step and the first compiled step's extra seconds, measured in one run; the network is eager afterwards."""
    from scapo.engine.speed import step_seconds

    job = _compile_job(False)
    batch = {"points": job.data.tensors["points"][:8, :32]}

    def step():
        _, total = job.stages[0].losses(batch, 0.0)
        total.backward()

    t = step_seconds(step, job.model, True, 2, False)
    assert set(t) == {"step_s", "eager_s", "compile_s"} and min(t.values()) >= 0 and t["step_s"] > 0
    assert job.model.body._compiled_call_impl is None
    assert set(step_seconds(step, job.model, False, 2, False)) == {"step_s"}
