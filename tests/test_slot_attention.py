"""Slot attention (scapo.nn.slot_attention, EAP's grouping): the GRU of each slot is nn.GRUCell's, and slots learn
to take two separated blobs apart."""

from __future__ import annotations

import pytest
import torch

from scapo.nn.slot_attention import SlotAttention


def test_each_slots_gru_is_a_torch_gru_cell():
    torch.manual_seed(0)
    sa = SlotAttention(3, 8, iters=1)
    cell = torch.nn.GRUCell(8, 8)
    with torch.no_grad():
        cell.weight_ih.copy_(sa.Wi[1].T)
        cell.bias_ih.copy_(sa.bi[1])
        cell.weight_hh.copy_(sa.Wh[1].T)
        cell.bias_hh.copy_(sa.bh[1])
    x, h = torch.randn(5, 3, 8), torch.randn(5, 3, 8)
    torch.testing.assert_close(sa._gru(x, h)[:, 1], cell(x[:, 1], h[:, 1]))


def test_slot_attention_assigns_two_separated_blobs_to_two_slots():
    """Two blobs of points 2 units apart (random directions, 0.1 spread), features a learned embedding; slot
    attention with a linear read-out trained to reconstruct each point from its slots (the competition over
    slots is the only way to do it). Every point of a blob goes to one slot, the blobs to different slots."""
    torch.manual_seed(0)
    D = 16
    emb, dec = torch.nn.Linear(3, D), torch.nn.Linear(D, 3)
    sa = SlotAttention(2, D, iters=3, hidden=32)
    opt = torch.optim.Adam([*sa.parameters(), *dec.parameters(), *emb.parameters()], lr=3e-3)

    def blobs(B, N=64):
        c = torch.nn.functional.normalize(torch.randn(B, 3), dim=-1)
        lab = torch.arange(N) % 2
        return torch.stack([c, -c], 1)[:, lab] + 0.1 * torch.randn(B, N, 3), lab

    for _ in range(300):
        x, _ = blobs(16)
        slots, attn = sa(torch.tanh(emb(x)))
        loss = ((torch.einsum("bsn,bsd->bnd", attn, dec(slots)) - x) ** 2).sum(-1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    sa.eval()
    with torch.no_grad():
        x, lab = blobs(32)
        _, attn = sa(torch.tanh(emb(x)))
        a0, a1 = sa(torch.tanh(emb(x)))[1].argmax(1), attn.argmax(1)
    torch.testing.assert_close(a0, a1)  # eval mode: deterministic
    for b in range(32):
        m0, m1 = a1[b, lab == 0].mode().values, a1[b, lab == 1].mode().values
        assert m0 != m1
        assert (a1[b, lab == 0] == m0).float().mean() >= 0.9 and (a1[b, lab == 1] == m1).float().mean() >= 0.9
    assert torch.allclose(attn.sum(1), torch.ones_like(attn[:, 0]), atol=1e-5)


def test_slot_attention_refuses_wrong_shapes():
    with pytest.raises(ValueError, match="expects"):
        SlotAttention(2, 8)(torch.randn(2, 5, 7))
    with pytest.raises(ValueError, match="num_slots"):
        SlotAttention(0, 8)
