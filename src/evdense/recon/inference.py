"""Running a reconstruction network over voxel grids, window by window, with its recurrent state.

:class:`NetworkReconstructor` normalises each voxel grid as the network was trained, runs it on
the CPU (channels-last, optionally bfloat16) or CUDA, and returns the frame in [0, 1]; the stage
that writes frame folders from it is :func:`evdense.recon.stage.run_recon`.
"""

from __future__ import annotations

import numpy as np
import torch

from evdense.log import get_logger
from evdense.recon.networks import ReconstructionNet, States
from evdense.recon.postprocess import standardize_nonzero

log = get_logger("recon")


def pick_device(name: str) -> torch.device:
    """``cpu``, ``cuda`` or ``auto`` (cuda when available) as a torch device."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def cpu_has_fast_bf16() -> bool:
    """Whether torch's CPU kernels run bfloat16 natively here (AVX-512 or AMX); on an AVX2-only
    CPU it is emulated (FireNet at 346x260: 1,003 ms per frame against 91 ms in float32)."""
    return torch.backends.cpu.get_cpu_capability() in ("AVX512", "AVX512_BF16", "AMX")


class NetworkReconstructor:
    """Run a recurrent network window after window, carrying its state.

    Args:
        net: the network (its weights loaded).
        normalize: "auto" (the network's own input normalisation), "nonzero" or "none".
        device: torch device.
        channels_last: channels-last memory layout for the network's tensors.
        precision: ``float32`` or ``bfloat16`` (weights, activations and recurrent state; the
            input voxels are normalised in float32 first, the frame is returned as float32).
        voxel_clip: cap on ``|voxel|`` (signed events per cell) applied before the
            normalisation; 0 = none. See ``ReconstructConfig.voxel_clip``.

    ``rec(voxel)`` takes one voxel grid ``(B, H, W)`` (any float dtype, not modified) and
    returns the frame ``(H, W)`` float32 in [0, 1]; ``rec.states`` is the recurrent state
    (assign it to hand a state over, ``rec.reset()`` to forget it).
    """

    def __init__(
        self,
        net: ReconstructionNet,
        normalize: str = "auto",
        device: str | torch.device = "cpu",
        channels_last: bool = True,
        precision: str = "float32",
        voxel_clip: float = 0.0,
    ) -> None:
        if not voxel_clip >= 0:
            raise ValueError(f"voxel_clip must be >= 0 (0 = off), not {voxel_clip!r}")
        self.voxel_clip = float(voxel_clip)
        if normalize not in ("auto", "nonzero", "none"):
            raise ValueError(f"normalize must be auto, nonzero or none, not {normalize!r}")
        self.device = torch.device(device)
        self.memory_format = torch.channels_last if channels_last else torch.contiguous_format
        dtypes = {"float32": torch.float32, "bfloat16": torch.bfloat16}
        if precision not in dtypes:
            raise ValueError(f"precision must be float32 or bfloat16, not {precision!r}")
        self.dtype = dtypes[precision]
        if self.dtype == torch.bfloat16 and self.device.type == "cpu" and not cpu_has_fast_bf16():
            log.warning(
                "precision bfloat16 on a CPU without AVX-512 (torch sees %s): bfloat16 is emulated "
                "there and about 10x slower than float32; use float32",
                torch.backends.cpu.get_cpu_capability(),
            )
        self.net = net.eval().to(self.device, self.dtype, memory_format=self.memory_format)
        self.normalization = net.input_normalization if normalize == "auto" else normalize
        self.states: States | None = None

    def reset(self) -> None:
        """Forget the recurrent state (the next window starts from zeros)."""
        self.states = None

    @torch.inference_mode()
    def __call__(self, voxel: np.ndarray | torch.Tensor) -> np.ndarray:
        x = torch.as_tensor(voxel, dtype=torch.float32)
        if x.ndim != 3 or x.shape[0] != self.net.num_bins:
            raise ValueError(
                f"expected a voxel grid (B={self.net.num_bins}, H, W), got shape {tuple(x.shape)}"
            )
        x = x.to(self.device, copy=True)[None]
        if self.voxel_clip > 0:
            x.clamp_(-self.voxel_clip, self.voxel_clip)
        if self.normalization == "nonzero":
            standardize_nonzero(x)
        x = x.to(self.dtype).contiguous(memory_format=self.memory_format)
        img, self.states = self.net(x, self.states)
        if self.net.output_range == "clip":
            img = img.clamp_(0.0, 1.0)
        return img[0, 0].float().cpu().numpy()

    def run(self, voxels: np.ndarray) -> np.ndarray:
        """Reconstruct a stream ``(W, B, H, W)`` in one pass, from the current state; frames ``(W, H, W)``."""
        return np.stack([self(v) for v in voxels])
