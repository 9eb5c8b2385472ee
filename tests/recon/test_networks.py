"""Reconstruction networks: published layouts, parameter counts, cell equations, padding, layouts."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from evdense.recon.networks import (
    E2VID,
    ConvGRU,
    ConvLSTM,
    FireNet,
    FireNetPlus,
    build_network,
    detach_states,
)


def test_parameter_counts_match_the_published_networks():
    assert E2VID().num_parameters() == 10_712_098  # E2VID lightweight
    assert FireNet().num_parameters() == 37_777
    assert FireNetPlus().num_parameters() == 37_777


def test_e2vid_state_dict_names_follow_rpg_e2vid():
    keys = set(E2VID().state_dict())
    for k in (
        "unetrecurrent.head.conv2d.weight",
        "unetrecurrent.head.conv2d.bias",
        "unetrecurrent.encoders.0.conv.conv2d.weight",
        "unetrecurrent.encoders.0.conv.norm_layer.running_var",
        "unetrecurrent.encoders.2.recurrent_block.Gates.weight",
        "unetrecurrent.resblocks.0.conv1.weight",
        "unetrecurrent.resblocks.1.bn2.weight",
        "unetrecurrent.decoders.0.transposed_conv2d.weight",
        "unetrecurrent.decoders.2.norm_layer.bias",
        "unetrecurrent.pred.conv2d.weight",
        "unetrecurrent.pred.norm_layer.weight",
    ):
        assert k in keys, k
    # batch norm replaces the conv biases; the 5x5 head has its bias (no norm)
    assert "unetrecurrent.encoders.0.conv.conv2d.bias" not in keys
    assert not any(k.startswith("unetrecurrent.encoders.3") for k in keys)
    sd = E2VID().state_dict()
    assert tuple(sd["unetrecurrent.encoders.0.recurrent_block.Gates.weight"].shape) == (
        256,
        128,
        3,
        3,
    )
    assert tuple(sd["unetrecurrent.decoders.0.transposed_conv2d.weight"].shape) == (256, 128, 5, 5)


def test_firenet_layouts():
    fk = set(FireNet().state_dict())
    assert "net.head.recurrent_block.update_gate.weight" in fk
    assert "net.resblocks.0.recurrent_block.out_gate.bias" in fk
    assert "net.resblocks.1.conv2.weight" in fk
    assert not any(k.startswith("net.resblocks.1.recurrent_block") for k in fk)
    pk = {k.split(".")[0] for k in FireNetPlus().state_dict()}
    assert pk == {"head", "G1", "R1", "G2", "R2", "pred"}


def test_conv_gru_follows_the_gru_equations():
    torch.manual_seed(0)
    cell = ConvGRU(3, 4, 3)
    x, h = torch.randn(2, 3, 9, 7), torch.randn(2, 4, 9, 7)
    xh = torch.cat((x, h), 1)
    z = torch.sigmoid(F.conv2d(xh, cell.update_gate.weight, cell.update_gate.bias, padding=1))
    r = torch.sigmoid(F.conv2d(xh, cell.reset_gate.weight, cell.reset_gate.bias, padding=1))
    o = torch.tanh(
        F.conv2d(torch.cat((x, r * h), 1), cell.out_gate.weight, cell.out_gate.bias, padding=1)
    )
    expected = h * (1 - z) + o * z
    torch.testing.assert_close(cell(x, h), expected, rtol=1e-5, atol=1e-6)
    # no state = zero state
    torch.testing.assert_close(cell(x, None), cell(x, torch.zeros_like(h)))


def test_conv_lstm_follows_the_lstm_equations():
    torch.manual_seed(1)
    cell = ConvLSTM(3, 2, 3)
    x, h, c = torch.randn(1, 3, 6, 5), torch.randn(1, 2, 6, 5), torch.randn(1, 2, 6, 5)
    g = F.conv2d(torch.cat((x, h), 1), cell.Gates.weight, cell.Gates.bias, padding=1)
    i, f, o, cc = g.chunk(4, 1)
    c_new = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(cc)
    h_new = torch.sigmoid(o) * torch.tanh(c_new)
    h2, c2 = cell(x, (h, c))
    torch.testing.assert_close(c2, c_new, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(h2, h_new, rtol=1e-5, atol=1e-6)


def test_e2vid_pads_to_multiple_of_8_and_crops_back():
    torch.manual_seed(0)
    net = E2VID(base_channels=8).eval()
    x = torch.randn(1, 5, 37, 50)
    with torch.inference_mode():
        img, states = net(x, None)
        img2, _ = net(x, states)
    assert img.shape == (1, 1, 37, 50)
    assert float(img.min()) > 0 and float(img.max()) < 1  # sigmoid
    # states live at the padded size (40 x 56) at 1/2, 1/4, 1/8 resolution
    assert [tuple(h.shape[-2:]) for h, _ in states] == [(20, 28), (10, 14), (5, 7)]
    assert not torch.equal(img, img2)  # the state matters


@pytest.mark.parametrize("arch", ["firenet", "firenet_plus", "e2vid"])
def test_channels_last_gives_the_same_frames(arch):
    torch.manual_seed(0)
    hp = {"base_channels": 8} if arch == "e2vid" else {}
    net = build_network(arch, **hp).eval()
    x = torch.randn(1, 5, 24, 32)
    with torch.inference_mode():
        a, sa = net(x, None)
        a, sa = net(x, sa)
        net_cl = net.to(memory_format=torch.channels_last)
        xc = x.contiguous(memory_format=torch.channels_last)
        b, sb = net_cl(xc, None)
        b, sb = net_cl(xc, sb)
    torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_hparams_rebuild_the_same_architecture_and_states_detach():
    net = FireNet(recurrent_resblocks=(0, 1))
    twin = FireNet(**net.hparams())
    assert set(twin.state_dict()) == set(net.state_dict())
    x = torch.randn(1, 5, 8, 8)
    _, states = net(x, None)
    assert len(states) == 3 and states[0].requires_grad
    assert not any(s.requires_grad for s in detach_states(states))
    with pytest.raises(ValueError, match="unknown network"):
        build_network("resnet")


@pytest.mark.parametrize("arch", ["firenet", "firenet_plus", "e2vid"])
@pytest.mark.parametrize("channels_last", [False, True])
def test_fused_inference_path_equals_the_plain_path(arch, channels_last):
    # inference on CPU fuses activations into oneDNN convolutions; with autograd on, the plain
    # modules run: both must give the same frames and states
    torch.manual_seed(0)
    hp = {"base_channels": 8} if arch == "e2vid" else {}
    net = build_network(arch, **hp).eval()
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.2)
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    net = net.to(memory_format=fmt)
    x = torch.randn(1, 5, 24, 40).contiguous(memory_format=fmt)
    a, sa = net(x, None)
    a, sa = net(x, sa)
    assert a.requires_grad
    with torch.inference_mode():
        b, sb = net(x, None)
        b, sb = net(x, sb)
    torch.testing.assert_close(a.detach(), b, rtol=1e-4, atol=1e-5)
    flat = lambda st: [t for s in st for t in (s if isinstance(s, tuple) else (s,))]  # noqa: E731
    for ta, tb in zip(flat(sa), flat(sb), strict=True):
        torch.testing.assert_close(ta.detach(), tb, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("arch", ["firenet", "firenet_plus", "e2vid"])
def test_gradients_flow_through_the_recurrent_state(arch):
    torch.manual_seed(0)
    hp = {"base_channels": 8} if arch == "e2vid" else {}
    net = build_network(arch, **hp)
    x = torch.randn(2, 5, 24, 32)
    states, loss = None, 0.0
    for _ in range(3):
        img, states = net(x, states)
        loss = loss + img.mean()
    loss.backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in net.parameters())
