"""OP-Align's real-world data format: a small synthetic file in that layout converts into a scapo dataset."""

import json

import numpy as np
import pytest
from quick import QUICK_ICP

from scapo.cli.main import main
from scapo.data import load
from scapo.data.opalign_real import convert_opalign_real, find_frames, read_frame
from scapo.errors import ConfigError, DatasetError
from scapo.ops.rigid import as_transform, joint_motion, transform_points

H, W, F, CX, CY = 96, 128, 120.0, 64.0, 48.0


def _frame(theta: float, tilt: float):
    """A laptop-like object: base plane and a screen hinged at its back edge, opened by ``theta`` (rad), seen from
    the camera (OpenCV frame), with a background wall; organised into an H x W image like OP-Align's files.
    Returns the dict stored in the file and the GT used to make it."""
    from scipy.spatial.transform import Rotation

    T_b = as_transform(Rotation.from_euler("x", -tilt).as_matrix(), [0.0, 0.0, 1.0])
    pivot_c, axis_c = np.array([-0.1, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    T_s = T_b @ joint_motion(0, axis_c, pivot_c, theta)
    g = np.linspace(-0.1, 0.1, 140)
    base_c = np.stack([*np.meshgrid(g, g, indexing="ij"), np.zeros((140, 140))], -1).reshape(-1, 3)
    zz = np.linspace(0.0, 0.2, 140)
    scr_c = np.stack([np.full((140, 140), -0.1), *np.meshgrid(g, zz, indexing="ij")], -1).reshape(-1, 3)
    pc = np.zeros((H * W, 3))
    seg = np.zeros(H * W, dtype=np.int64)
    x = np.concatenate([transform_points(T_b, base_c), transform_points(T_s, scr_c)])
    lab = np.repeat([1, 2], [len(base_c), len(scr_c)])
    u = np.round(F * x[:, 0] / x[:, 2] + CX).astype(int)
    v = np.round(F * x[:, 1] / x[:, 2] + CY).astype(int)
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    x, lab, k = x[ok], lab[ok], (v * W + u)[ok]
    order = np.lexsort((x[:, 2], k))  # by pixel, nearest first: a z-buffer
    first = order[np.r_[True, k[order][1:] != k[order][:-1]]]
    pc[k[first]], seg[k[first]] = x[first], lab[first]
    obj = seg > 0
    vv, uu = np.divmod(np.arange(H * W), W)
    wall = ~obj
    pc[wall] = np.stack([(uu[wall] - CX) / F * 1.5, (vv[wall] - CY) / F * 1.5, np.full(wall.sum(), 1.5)], 1)
    pc[wall & (uu < 2)] = 0.0  # no depth on the left border
    from scipy.ndimage import binary_dilation

    detection = binary_dilation(obj.reshape(H, W), iterations=1).reshape(-1)
    part = np.stack([np.concatenate([T[:3, :3].reshape(-1), T[:3, 3], s])
                     for T, s in ((T_b, [0.2, 0.2, 0.01]), (T_s, [0.01, 0.2, 0.2]))])
    joint = np.concatenate([transform_points(T_b, pivot_c[None])[0], T_b[:3, :3] @ axis_c])[None]
    raw = {"pc": pc, "color": np.zeros_like(pc), "detection": detection, "segmentation": seg, "part": part,
           "joint": joint}
    return raw, {"T": (T_b, T_s), "theta": theta, "ring": detection & ~obj}


@pytest.fixture(scope="module")
def real_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("laptop_output")
    gts = {}
    for split, insts in (("train", ("a", "b", "c")), ("test", ("d",))):
        for i, a in enumerate(insts):
            for k in range(2):
                raw, gt = _frame(0.4 + 0.3 * k + 0.1 * i, 0.5 + 0.05 * k)
                d = root / split / a / "seq0" / "input_2"
                d.mkdir(parents=True, exist_ok=True)
                np.savez(d / f"{k:04d}.npz", raw)
                gts[f"{split}/{a}/seq0/input_2/{k:04d}.npz"] = (raw, gt)
    return root, gts


def test_frame_fields_follow_the_loader_pivot_first(real_root):
    root, gts = real_root
    f = sorted(find_frames(root)["train"])[0][1]
    raw = read_frame(f)
    assert raw["joint"].shape == (1, 6) and raw["part"].shape == (2, 15)


def test_conversion_gives_exact_ground_truth(real_root, tmp_path):
    root, gts = real_root
    out = tmp_path / "real"
    card = convert_opalign_real(root, "laptop", out, num_points=128, seed=0, val_fraction=0.34, image_size=(H, W))
    assert card["part_names"] == ["base", "screen"] and card["joint_type"] == [0]
    assert {s: v["samples"] for s, v in card["splits"].items()} == {"train": 4, "val": 2, "test": 2}
    import pandas as pd

    m = pd.read_parquet(out / "manifest.parquet")
    for split in ("train", "val", "test"):
        ds = load(out, split)
        for i in range(len(ds)):
            s = ds[i]
            raw, gt = gts[m[m["split"] == split]["source_file"].iloc[i]]
            np.testing.assert_allclose(s["K"], [[F, 0, CX], [0, F, CY], [0, 0, 1]], atol=0.6)
            assert s["joint_state"][0] == pytest.approx(gt["theta"], abs=1e-9)
            np.testing.assert_allclose(s["joint_pivot"][0], raw["joint"][0, :3])  # pivot first, as the loader
            np.testing.assert_allclose(s["joint_axis"][0], raw["joint"][0, 3:])
            np.testing.assert_allclose(s["part_pose"], np.stack(gt["T"]), atol=1e-9)
            lab, pts = s["part_label"], s["points"].astype(np.float64)
            assert set(np.unique(lab)) <= {-1, 0, 1} and (lab == 0).any() and (lab == 1).any()
            # labelled points map back onto their part's canonical plane (npcs * bbox_diag)
            c = s["npcs"] * s["bbox_diag"]
            assert np.abs(c[lab == 0, 2]).max() < 1e-5 and np.abs(c[lab == 1, 0] + 0.1).max() < 1e-5
            # background only from the detection mask (its ring around the object), never the wall beyond
            ring = raw["pc"][gt["ring"]]
            bg = pts[lab < 0]
            assert all(np.abs(ring - p).sum(1).min() < 1e-6 for p in bg)
    # rerunning rewrites the same dataset; other arguments into the same folder are refused
    assert convert_opalign_real(root, "laptop", out, num_points=128, seed=0, val_fraction=0.34,
                                image_size=(H, W))["dataset_hash"] == card["dataset_hash"]
    with pytest.raises(ConfigError, match="not empty"):
        convert_opalign_real(root, "laptop", out, num_points=64, image_size=(H, W))


def test_bad_frames_and_skips(real_root, tmp_path):
    root, _ = real_root
    with pytest.raises(ConfigError, match=r"every frame was skipped \(\{'too few object pixels': 8\}\)"):
        convert_opalign_real(root, "laptop", tmp_path / "few", num_points=H * W, image_size=(H, W))
    bad = tmp_path / "bad.npz"
    np.savez(bad, {"pc": np.zeros((4, 3))})
    with pytest.raises(DatasetError, match="lacks fields"):
        read_frame(bad)
    with pytest.raises(ConfigError, match="no known joints"):
        convert_opalign_real(root, "teapot", tmp_path / "t", image_size=(H, W))


def test_cli_convert_then_icp_predict_and_evaluate(real_root, tmp_path):
    root, _ = real_root
    d = tmp_path / "ds"
    assert main(["convert", "opalign-real", "--root", str(root), "--category", "laptop", "--points", "400",
                 "--image-size", f"{H}x{W}", "--out", str(d)]) == 0
    assert json.loads((d / "card.json").read_text())["source"]["kind"] == "op-align-real"
    assert main(["predict", "--method", "icp", "--data", str(d), "--out", str(tmp_path / "p.npz"), *QUICK_ICP]) == 0
    assert main(["evaluate", "--data", str(d), "--pred", str(tmp_path / "p.npz"), "--out", str(tmp_path / "t")]) == 0
    assert main(["preview", "--data", str(d), "--count", "1", "--out", str(tmp_path / "p.png")]) == 0


def test_frames_with_a_zero_axis_or_a_segmentation_id_beyond_the_parts_are_refused():
    from scapo.data.opalign_real import frame_to_sample
    from scapo.errors import InputError

    raw, _ = _frame(0.5, 0.3)
    frame = {k: np.asarray(v) for k, v in raw.items() if k != "color"}
    frame["detection"] = frame["detection"].astype(bool)
    rng = np.random.default_rng(0)
    sample = frame_to_sample(frame, [0], [[0, 1]], 256, rng, (H, W))
    assert set(np.unique(sample["part_label"])) <= {-1, 0, 1}
    zero = {**frame, "joint": np.concatenate([frame["joint"][:, :3], np.zeros((1, 3))], 1)}
    with pytest.raises(InputError, match="zero-length axis"):
        frame_to_sample(zero, [0], [[0, 1]], 256, rng, (H, W))
    seg = frame["segmentation"].copy()
    seg[seg == 2] = 3  # a third part id on a two-part object
    with pytest.raises(InputError, match="segmentation ids up to 3"):
        frame_to_sample({**frame, "segmentation": seg}, [0], [[0, 1]], 256, rng, (H, W))
    neg = frame["segmentation"].copy()
    neg[neg == 2] = -4  # an id below background
    with pytest.raises(InputError, match="segmentation ids down to -4"):
        frame_to_sample({**frame, "segmentation": neg}, [0], [[0, 1]], 256, rng, (H, W))
    with pytest.raises(InputError, match="all background"):
        frame_to_sample({**frame, "segmentation": np.zeros_like(neg)}, [0], [[0, 1]], 256, rng, (H, W))


def test_a_known_categorys_joints_are_not_relabelled(real_root, tmp_path):
    root, _ = real_root
    with pytest.raises(ConfigError, match="would relabel them"):
        convert_opalign_real(root, "laptop", tmp_path / "slide", joint_type=[1], joint_parts=[[0, 1]],
                             image_size=(H, W))
    assert not (tmp_path / "slide").exists()
