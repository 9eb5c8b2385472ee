"""Recurrent networks that turn voxel grids of events into intensity frames.

Three families, each with the parameter names of its published checkpoint so that the published
weights load with no key renamed:

- :class:`FireNet` (Scheerlinck et al., WACV 2020): a ConvGRU head, a recurrent residual block, a
  residual block and a 1x1 prediction, all at full resolution, 16 channels (37,777 parameters).
  Keys ``net.head.*``, ``net.resblocks.0.*``, ``net.resblocks.1.*``, ``net.pred.*``.
- :class:`FireNetPlus` (Stoffregen et al., ECCV 2020): head, ConvGRU, residual block, ConvGRU,
  residual block, prediction (37,777 parameters). Keys ``head``, ``G1``, ``R1``, ``G2``, ``R2``,
  ``pred``.
- :class:`E2VID` (Rebecq et al., TPAMI 2019), the recurrent UNet: a 5x5 head, stride-2 encoders
  each followed by a ConvLSTM, residual blocks, transposed-convolution decoders with summed skip
  connections, a 1x1 prediction and a sigmoid. With the defaults (3 encoders, 32 base channels,
  batch norm) it is the published "E2VID lightweight" (10,712,098 parameters), keys
  ``unetrecurrent.*``.

Every network maps a voxel grid ``(N, B, H, W)`` and the recurrent state of the previous window
to an image ``(N, 1, H, W)`` and the new state: ``img, states = net(x, states)``. The state is a
list with one entry per recurrent unit (a tensor for a ConvGRU, a ``(hidden, cell)`` pair for a
ConvLSTM); ``None`` starts from zeros. Networks keep no state themselves, so the caller decides
when to carry it over and when to reset it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

GRUState = Tensor
LSTMState = tuple[Tensor, Tensor]
States = list[Any]

ARCHITECTURES = ("firenet", "firenet_plus", "e2vid")

# oneDNN convolution with a fused activation (and residual sum), the op torch.compile uses on
# CPU. It saves one pass over the feature map per activation; used only for inference on CPU
# (it has no autograd), with the plain path as fallback.
_POINTWISE = getattr(torch.ops.mkldnn, "_convolution_pointwise", None)
FUSED_INFERENCE = True
"""Use the fused oneDNN path at CPU inference (set False to run the plain modules, e.g. to compare)."""


def _use_fused(x: Tensor) -> bool:
    return (
        FUSED_INFERENCE
        and _POINTWISE is not None
        and not torch.is_grad_enabled()
        and x.device.type == "cpu"
        and x.dtype == torch.float32
    )


def conv_act(x: Tensor, conv: nn.Conv2d, act: str | None = None) -> Tensor:
    """``act(conv(x))`` with ``act`` in None, "relu", "sigmoid", "tanh" (fused on CPU inference)."""
    if _use_fused(x):
        return _POINTWISE(
            x, conv.weight, conv.bias, list(conv.padding), list(conv.stride),
            list(conv.dilation), conv.groups, act or "none", [], "",
        )  # fmt: skip
    y = conv(x)
    if act == "relu":
        return y.relu_()
    if act == "sigmoid":
        return y.sigmoid_()
    if act == "tanh":
        return y.tanh_()
    return y


def conv_add_relu(x: Tensor, residual: Tensor, conv: nn.Conv2d) -> Tensor:
    """``relu(conv(x) + residual)`` (fused on CPU inference)."""
    if _use_fused(x) and residual.is_contiguous(memory_format=_layout(x)):
        return _POINTWISE.binary(
            x, residual, conv.weight, conv.bias, list(conv.padding), list(conv.stride),
            list(conv.dilation), conv.groups, "add", None, "relu", [], "",
        )  # fmt: skip
    return (conv(x) + residual).relu_()


def _layout(x: Tensor) -> torch.memory_format:
    return (
        torch.channels_last
        if x.dim() == 4 and x.is_contiguous(memory_format=torch.channels_last)
        else torch.contiguous_format
    )


# ---------------------------------------------------------------------------------------------
# Blocks (attribute names follow the published checkpoints: conv2d, norm_layer, Gates, ...)
# ---------------------------------------------------------------------------------------------


class ConvLayer(nn.Module):
    """Convolution, optional batch norm, optional ReLU. Keys: ``conv2d``, ``norm_layer``."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int,
        stride: int = 1,
        padding: int = 0,
        relu: bool = True,
        batch_norm: bool = False,
    ) -> None:
        super().__init__()
        self.conv2d = nn.Conv2d(
            in_channels, out_channels, kernel_size, stride, padding, bias=not batch_norm
        )
        self.norm_layer = nn.BatchNorm2d(out_channels) if batch_norm else None
        self.relu = relu

    def forward(self, x: Tensor) -> Tensor:
        if self.norm_layer is None:
            return conv_act(x, self.conv2d, "relu" if self.relu else None)
        x = self.norm_layer(self.conv2d(x))
        return F.relu(x) if self.relu else x


class TransposedConvLayer(nn.Module):
    """Stride-2 transposed convolution (doubles H and W), optional batch norm, ReLU.

    Key: ``transposed_conv2d``, ``norm_layer``.
    """

    def __init__(
        self, in_channels: int, out_channels: int, kernel_size: int, batch_norm: bool = False
    ) -> None:
        super().__init__()
        self.transposed_conv2d = nn.ConvTranspose2d(
            in_channels,
            out_channels,
            kernel_size,
            stride=2,
            padding=kernel_size // 2,
            output_padding=1,
            bias=not batch_norm,
        )
        self.norm_layer = nn.BatchNorm2d(out_channels) if batch_norm else None

    def forward(self, x: Tensor) -> Tensor:
        x = self.transposed_conv2d(x)
        if self.norm_layer is not None:
            x = self.norm_layer(x)
        return F.relu(x)


class ResidualBlock(nn.Module):
    """Two 3x3 convolutions (optional batch norm) with an identity shortcut, ReLU after the sum.

    Keys: ``conv1``, ``conv2``, ``bn1``, ``bn2``.
    """

    def __init__(self, channels: int, batch_norm: bool = False) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=1, bias=not batch_norm)
        self.bn1 = nn.BatchNorm2d(channels) if batch_norm else None
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1, bias=not batch_norm)
        self.bn2 = nn.BatchNorm2d(channels) if batch_norm else None

    def forward(self, x: Tensor) -> Tensor:
        if self.bn1 is None:
            return conv_add_relu(conv_act(x, self.conv1, "relu"), x, self.conv2)
        out = F.relu(self.bn1(self.conv1(x)))
        return F.relu(self.bn2(self.conv2(out)) + x)


class ConvGRU(nn.Module):
    """Convolutional GRU cell. Keys: ``reset_gate``, ``update_gate``, ``out_gate``.

    ``h' = (1 - z) * h + z * tanh(W_o [x, r * h])`` with ``z = sigmoid(W_z [x, h])`` and
    ``r = sigmoid(W_r [x, h])``.
    """

    def __init__(self, input_size: int, hidden_size: int, kernel_size: int = 3) -> None:
        super().__init__()
        self.input_size = input_size
        self.hidden_size = hidden_size
        pad = kernel_size // 2
        n_in = input_size + hidden_size
        self.reset_gate = nn.Conv2d(n_in, hidden_size, kernel_size, padding=pad)
        self.update_gate = nn.Conv2d(n_in, hidden_size, kernel_size, padding=pad)
        self.out_gate = nn.Conv2d(n_in, hidden_size, kernel_size, padding=pad)
        for conv in (self.reset_gate, self.update_gate, self.out_gate):
            nn.init.orthogonal_(conv.weight)
            nn.init.zeros_(conv.bias)

    def forward(self, x: Tensor, h: Tensor | None) -> Tensor:
        if h is None:
            shape = (x.shape[0], self.hidden_size, x.shape[2], x.shape[3])
            h = torch.empty(shape, dtype=x.dtype, device=x.device, memory_format=_layout(x)).zero_()
        xh = torch.cat((x, h), dim=1)
        n = self.hidden_size
        if not _use_fused(x):
            z = torch.sigmoid(self.update_gate(xh))
            r = torch.sigmoid(self.reset_gate(xh))
            candidate = torch.tanh(self.out_gate(torch.cat((x, r * h), dim=1)))
            return torch.lerp(h, candidate, z)
        # Inference: one convolution for both gates, the sigmoid and tanh fused into the
        # convolutions, r * h written over the h half of [x, h] (saves a second concatenation),
        # the new state written over the candidate. Fewer passes over memory, same result.
        zr = _POINTWISE(
            xh,
            torch.cat((self.update_gate.weight, self.reset_gate.weight), dim=0),
            torch.cat((self.update_gate.bias, self.reset_gate.bias), dim=0),
            list(self.update_gate.padding), [1, 1], [1, 1], 1, "sigmoid", [], "",
        )  # fmt: skip
        torch.mul(zr[:, n:], h, out=xh[:, self.input_size :])
        candidate = conv_act(xh, self.out_gate, "tanh")
        return torch.lerp(h, candidate, zr[:, :n], out=candidate)


class ConvLSTM(nn.Module):
    """Convolutional LSTM cell; one convolution ``Gates`` computes the four gates.

    Gate order along channels (as published): input, forget ("remember"), output, cell.
    """

    def __init__(self, input_size: int, hidden_size: int, kernel_size: int = 3) -> None:
        super().__init__()
        self.input_size = input_size
        self.hidden_size = hidden_size
        self.Gates = nn.Conv2d(
            input_size + hidden_size, 4 * hidden_size, kernel_size, padding=kernel_size // 2
        )

    def forward(self, x: Tensor, state: LSTMState | None) -> LSTMState:
        if state is None:
            shape = (x.shape[0], self.hidden_size, x.shape[2], x.shape[3])
            zeros = torch.empty(shape, dtype=x.dtype, device=x.device, memory_format=_layout(x))
            state = (zeros.zero_(), zeros)
        h, c = state
        gates = self.Gates(torch.cat((x, h), dim=1))
        n = self.hidden_size
        if torch.is_grad_enabled():
            ifo = torch.sigmoid(gates[:, : 3 * n])
            g = torch.tanh(gates[:, 3 * n :])
        else:  # in place: two fewer feature maps allocated per step
            ifo = gates[:, : 3 * n].sigmoid_()
            g = gates[:, 3 * n :].tanh_()
        i, f, o = ifo[:, :n], ifo[:, n : 2 * n], ifo[:, 2 * n :]
        c = torch.addcmul(f * c, i, g)
        h = o * torch.tanh(c)
        return h, c


def _make_cell(kind: str, channels: int) -> nn.Module:
    if kind == "convgru":
        return ConvGRU(channels, channels, 3)
    if kind == "convlstm":
        return ConvLSTM(channels, channels, 3)
    raise ValueError(f"unknown recurrent block type {kind!r} (convgru or convlstm)")


def _hidden(state: Tensor | LSTMState) -> Tensor:
    return state[0] if isinstance(state, tuple) else state


class RecurrentConvLayer(nn.Module):
    """A :class:`ConvLayer` followed by a recurrent cell. Keys: ``conv``, ``recurrent_block``."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int,
        stride: int = 1,
        padding: int = 0,
        recurrent_block_type: str = "convlstm",
        batch_norm: bool = False,
    ) -> None:
        super().__init__()
        self.conv = ConvLayer(
            in_channels, out_channels, kernel_size, stride, padding, batch_norm=batch_norm
        )
        self.recurrent_block = _make_cell(recurrent_block_type, out_channels)

    def forward(self, x: Tensor, state: Any) -> tuple[Tensor, Any]:
        state = self.recurrent_block(self.conv(x), state)
        return _hidden(state), state


class RecurrentResidualLayer(nn.Module):
    """A :class:`ResidualBlock` followed by a recurrent cell. Keys: ``conv``, ``recurrent_block``."""

    def __init__(
        self, channels: int, recurrent_block_type: str = "convgru", batch_norm: bool = False
    ) -> None:
        super().__init__()
        self.conv = ResidualBlock(channels, batch_norm=batch_norm)
        self.recurrent_block = _make_cell(recurrent_block_type, channels)

    def forward(self, x: Tensor, state: Any) -> tuple[Tensor, Any]:
        state = self.recurrent_block(self.conv(x), state)
        return _hidden(state), state


# ---------------------------------------------------------------------------------------------
# Networks
# ---------------------------------------------------------------------------------------------


class ReconstructionNet(nn.Module):
    """Common interface: ``img, states = net(voxels (N, B, H, W), states)``.

    Class attributes say how to use the network: ``arch`` (its name in checkpoints),
    ``input_normalization`` ("nonzero": non-zero voxels standardised to mean 0, std 1, as the
    network was trained; "none": raw voxels) and ``output_range`` ("sigmoid": already in [0, 1];
    "clip": clip the raw prediction to [0, 1]).
    """

    arch: str = ""
    input_normalization: str = "nonzero"
    output_range: str = "clip"

    _hp: dict[str, Any]

    def hparams(self) -> dict[str, Any]:
        """Constructor arguments; ``type(net)(**net.hparams())`` builds the same architecture."""
        return dict(self._hp)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def _arguments(scope: dict[str, Any]) -> dict[str, Any]:
    """A constructor's arguments from its ``locals()`` taken first thing (tuples as lists, as a
    checkpoint's JSON stores them)."""
    return {
        k: list(v) if isinstance(v, tuple) else v
        for k, v in scope.items()
        if k not in ("self", "__class__")
    }


class _FireNetCore(nn.Module):
    """The ``net`` submodule of :class:`FireNet` (published name: UNetFire)."""

    def __init__(
        self,
        num_bins: int,
        base_channels: int,
        kernel_size: int,
        num_residual_blocks: int,
        recurrent_resblocks: tuple[int, ...],
    ) -> None:
        super().__init__()
        self.head = RecurrentConvLayer(
            num_bins, base_channels, kernel_size, padding=kernel_size // 2,
            recurrent_block_type="convgru",
        )  # fmt: skip
        self.recurrent_resblocks = tuple(recurrent_resblocks)
        self.resblocks = nn.ModuleList(
            RecurrentResidualLayer(base_channels, "convgru")
            if i in self.recurrent_resblocks
            else ResidualBlock(base_channels)
            for i in range(num_residual_blocks)
        )
        self.pred = ConvLayer(base_channels, 1, 1, relu=False)


class FireNet(ReconstructionNet):
    """FireNet (Scheerlinck et al., WACV 2020): 37,777 parameters with the defaults.

    Args:
        num_bins: temporal bins B of the input voxel grid.
        base_channels: feature channels at every layer.
        kernel_size: kernel of the head convolution.
        num_residual_blocks: residual blocks after the head.
        recurrent_resblocks: indices of the residual blocks followed by a ConvGRU.
    """

    arch = "firenet"
    input_normalization = "nonzero"
    output_range = "clip"

    def __init__(
        self,
        num_bins: int = 5,
        base_channels: int = 16,
        kernel_size: int = 3,
        num_residual_blocks: int = 2,
        recurrent_resblocks: tuple[int, ...] = (0,),
    ) -> None:
        hp = _arguments(locals())
        super().__init__()
        self._hp = hp
        self.num_bins = num_bins
        self.net = _FireNetCore(
            num_bins, base_channels, kernel_size, num_residual_blocks, tuple(recurrent_resblocks)
        )

    def forward(self, x: Tensor, states: States | None = None) -> tuple[Tensor, States]:
        n = self.net
        prev = states if states is not None else [None] * (1 + len(n.recurrent_resblocks))
        x, s = n.head(x, prev[0])
        new = [s]
        for i, block in enumerate(n.resblocks):
            if i in n.recurrent_resblocks:
                x, s = block(x, prev[len(new)])
                new.append(s)
            else:
                x = block(x)
        # The published FireNet has no skip connection to the prediction ("no_skip").
        return n.pred(x), new


class FireNetPlus(ReconstructionNet):
    """FireNet+ (Stoffregen et al., ECCV 2020): head, G1, R1, G2, R2, pred; 37,777 parameters.

    Trained on raw (not normalised) voxel grids; its output is clipped to [0, 1].
    """

    arch = "firenet_plus"
    input_normalization = "none"
    output_range = "clip"

    def __init__(self, num_bins: int = 5, base_channels: int = 16, kernel_size: int = 3) -> None:
        hp = _arguments(locals())
        super().__init__()
        self._hp = hp
        self.num_bins = num_bins
        c = base_channels
        self.head = ConvLayer(num_bins, c, kernel_size, padding=kernel_size // 2)
        self.G1 = ConvGRU(c, c, kernel_size)
        self.R1 = ResidualBlock(c)
        self.G2 = ConvGRU(c, c, kernel_size)
        self.R2 = ResidualBlock(c)
        self.pred = ConvLayer(c, 1, 1, relu=False)

    def forward(self, x: Tensor, states: States | None = None) -> tuple[Tensor, States]:
        s0, s1 = states if states is not None else (None, None)
        x = self.head(x)
        s0 = self.G1(x, s0)
        x = self.R1(s0)
        s1 = self.G2(x, s1)
        x = self.R2(s1)
        return self.pred(x), [s0, s1]


class _UNetRecurrent(nn.Module):
    """The ``unetrecurrent`` submodule of :class:`E2VID` (published name: UNetRecurrent)."""

    def __init__(
        self,
        num_bins: int,
        base_channels: int,
        num_encoders: int,
        num_residual_blocks: int,
        batch_norm: bool,
        recurrent_block_type: str,
        kernel_size: int,
    ) -> None:
        super().__init__()
        pad = kernel_size // 2
        self.head = ConvLayer(num_bins, base_channels, kernel_size, padding=pad)
        enc_in = [base_channels * 2**i for i in range(num_encoders)]
        enc_out = [base_channels * 2 ** (i + 1) for i in range(num_encoders)]
        self.encoders = nn.ModuleList(
            RecurrentConvLayer(
                cin, cout, kernel_size, stride=2, padding=pad,
                recurrent_block_type=recurrent_block_type, batch_norm=batch_norm,
            )
            for cin, cout in zip(enc_in, enc_out, strict=True)
        )  # fmt: skip
        self.resblocks = nn.ModuleList(
            ResidualBlock(enc_out[-1], batch_norm=batch_norm) for _ in range(num_residual_blocks)
        )
        self.decoders = nn.ModuleList(
            TransposedConvLayer(c, c // 2, kernel_size, batch_norm=batch_norm)
            for c in reversed(enc_out)
        )
        self.pred = ConvLayer(base_channels, 1, 1, relu=False, batch_norm=batch_norm)


class E2VID(ReconstructionNet):
    """Recurrent UNet of E2VID (Rebecq et al., TPAMI 2019); defaults give E2VID lightweight.

    With the defaults it has exactly 10,712,098 parameters and the state_dict names of the
    published ``E2VID_lightweight.pth.tar`` (``unetrecurrent.head.conv2d.weight``, ...).
    The input is zero-padded (centred) to a multiple of ``2**num_encoders`` pixels and the
    output cropped back, so any ``(H, W)`` works; the recurrent state lives at the padded size.

    Args:
        num_bins: temporal bins B of the input voxel grid.
        base_channels: channels after the head; doubled by every encoder.
        num_encoders: stride-2 encoders (each followed by a recurrent cell).
        num_residual_blocks: residual blocks at the bottleneck.
        norm: "BN" (batch norm) or "none".
        recurrent_block_type: "convlstm" or "convgru".
        kernel_size: kernel of the head, encoders and decoders.
    """

    arch = "e2vid"
    input_normalization = "nonzero"
    output_range = "sigmoid"

    def __init__(
        self,
        num_bins: int = 5,
        base_channels: int = 32,
        num_encoders: int = 3,
        num_residual_blocks: int = 2,
        norm: str = "BN",
        recurrent_block_type: str = "convlstm",
        kernel_size: int = 5,
    ) -> None:
        hp = _arguments(locals())
        super().__init__()
        if norm not in ("BN", "none"):
            raise ValueError(f"E2VID: norm must be 'BN' or 'none', not {norm!r}")
        self._hp = hp
        self.num_bins = num_bins
        self.num_encoders = num_encoders
        self.unetrecurrent = _UNetRecurrent(
            num_bins,
            base_channels,
            num_encoders,
            num_residual_blocks,
            norm == "BN",
            recurrent_block_type,
            kernel_size,
        )

    @property
    def pad_multiple(self) -> int:
        """Input H and W are padded to a multiple of this (pixels)."""
        return 2**self.num_encoders

    def forward(self, x: Tensor, states: States | None = None) -> tuple[Tensor, States]:
        u = self.unetrecurrent
        h, w = x.shape[-2:]
        m = self.pad_multiple
        ph, pw = math.ceil(h / m) * m - h, math.ceil(w / m) * m - w
        top, left = (ph + 1) // 2, (pw + 1) // 2
        if ph or pw:
            x = F.pad(x, (left, pw - left, top, ph - top))
        prev = states if states is not None else [None] * len(u.encoders)
        x = u.head(x)
        head = x
        skips, new = [], []
        for enc, s in zip(u.encoders, prev, strict=True):
            x, s = enc(x, s)
            skips.append(x)
            new.append(s)
        for block in u.resblocks:
            x = block(x)
        for dec, skip in zip(u.decoders, reversed(skips), strict=True):
            x = dec(x + skip)
        img = torch.sigmoid(u.pred(x + head))
        if ph or pw:
            img = img[..., top : top + h, left : left + w]
        return img, new


NETWORKS: dict[str, type[ReconstructionNet]] = {
    "firenet": FireNet,
    "firenet_plus": FireNetPlus,
    "e2vid": E2VID,
}


def build_network(arch: str, **hparams: Any) -> ReconstructionNet:
    """Build the network named ``arch`` (firenet, firenet_plus, e2vid) with these hyper-parameters."""
    if arch not in NETWORKS:
        raise ValueError(f"unknown network {arch!r}; known: {', '.join(NETWORKS)}")
    return NETWORKS[arch](**hparams)


def zero_states(states: States | None, rows: Tensor) -> States | None:
    """``states`` with the batch rows where the bool ``rows`` ``(N,)`` is true set to zero (those
    sequences start anew); None when there is no state or every row starts anew."""
    if states is None or bool(rows.all()):
        return None
    keep = (~rows).to(dtype=torch.float32).view(-1, 1, 1, 1)
    return _map_states(states, lambda t: t * keep.to(t.dtype))


def detach_states(states: States | None) -> States | None:
    """A copy of the recurrent state cut from the autograd graph (for truncated BPTT)."""
    if states is None:
        return None
    return _map_states(states, Tensor.detach)


def _map_states(states: States, fn: Callable[[Tensor], Tensor]) -> States:
    """``fn`` applied to every tensor of a state list (layers without state stay None, an
    LSTM's ``(h, c)`` stays a pair)."""
    return [
        None if s is None else tuple(fn(t) for t in s) if isinstance(s, tuple) else fn(s)
        for s in states
    ]
