"""SCAPO's forward pass returns typed outputs (scapo.nn.outputs) with the shapes their docstring gives."""

import dataclasses

import pytest
import torch

from scapo.models.scapo_model import ModelConfig, SCAPOModel
from scapo.nn.encoder import EncoderConfig
from scapo.nn.outputs import SCAPOOutput, Stage1Output


def test_forward_returns_typed_outputs_of_the_documented_shapes():
    cfg = ModelConfig(num_parts=2, joint_types=(0,), joint_parts=((0, 1),),
                      encoder=EncoderConfig(k=4, rot_channels=(8,), trans_channels=(4,), code_dim=8,
                                            decoder_hidden=(16, 16), decoder_points=32), template_points=24)
    torch.manual_seed(0)
    model = SCAPOModel(cfg)
    X = torch.randn(3, 40, 3)
    s1 = model(X, stage=1)
    assert type(s1) is Stage1Output and s1.X_rec.shape == (3, 32, 3) and s1.enc.R.shape == (3, 3, 3)
    out = model(X, stage=2)
    assert isinstance(out, SCAPOOutput)
    B, N, P, J, M = 3, 40, 2, 1, 24
    want = {"R": (B, 3, 3), "S_obj": (B, N, 3), "K": (B, P, 3), "V": (B, P, 3, 3), "log_scale": (B, P, 3),
            "w": (B, N, P), "Y": (B, M, 3), "delta": (B, M, 3), "pivot_x": (B, J, 3), "axis_x": (B, J, 3),
            "state_x": (B, J), "T_x": (B, P, 4, 4), "T_xy": (B, P, 4, 4), "S_star": (B, N, 3), "w_star": (B, N, P),
            "X_hat": (B, N, 3), "Y_hat": (B, M, 3), "S_x2y": (B, N, 3), "S_y2x": (B, M, 3)}
    for name, shape in want.items():
        assert tuple(getattr(out, name).shape) == shape, name
    assert {f.name for f in dataclasses.fields(out)} >= set(want)
    assert out["S_star"] is out.S_star  # read access by name, as the dict outputs had
    with pytest.raises(KeyError):
        out["nope"]
