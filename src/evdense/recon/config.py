"""Options of the reconstruction stage and their resolution from the workflow config (no torch import).

Kept apart from :mod:`evdense.recon.inference` so that Snakemake can resolve presets while it
builds the job graph without importing torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from evdense.config import section_from_dict

BASELINES = ("highpass", "integrate")


@dataclass
class ReconstructConfig:
    """How to turn windows into frames (one method, resolved from the config's presets)."""

    method: str = "firenet"
    """A network name with a checkpoint (firenet, firenet_plus, e2vid, ours, ...) or a baseline (highpass, integrate)."""
    checkpoint: str | None = None
    """Weights of a network method (our .pt + .json, or a published checkpoint); unused by baselines."""
    normalize: str = "auto"
    """Network input normalisation: auto (as the network was trained: non-zero voxels to mean 0, std
    1 for E2VID and FireNet, raw voxels for FireNet+), nonzero, or none."""
    voxel_clip: float = 3.0
    """Networks: cap on |voxel| (signed events per cell) before the input normalisation; 0 = off. An
    edge of high contrast (a sunlit patch beside shadow) fires tens of events per pixel at once;
    uncapped, those cells set the normalisation's spread and the texture elsewhere fades to nothing
    (room at 10^5: refined-mesh F 0.54 uncapped, 0.84 at 3). At ordinary contrast fewer than 0.3 %
    of the non-zero cells exceed 3."""
    max_gap_s: float = 0.5
    """Reset the recurrent state when a window starts more than this many seconds after the previous one ended."""
    device: str = "cpu"
    """Torch device of the networks (cpu, cuda, cuda:1, or auto = cuda when available)."""
    channels_last: bool = True
    """Run networks in channels-last memory layout (faster on CPU with oneDNN)."""
    precision: str = "float32"
    """Number format of the network's weights, activations and recurrent state: float32, or bfloat16
    (about 1.6x faster on CPUs with AVX-512 BF16 or AMX and on recent GPUs; frames within about 2
    grey levels of float32; about 10x slower than float32 on AVX2-only CPUs, where it is emulated:
    the stage warns)."""
    auto_hdr: bool = False
    """Rescale network frames with a robust min/max (percentiles) median-filtered over recent
    frames. Always on for the baselines, whose log intensity has no absolute scale."""
    hdr_min_percentile: float = 1.0
    """Percentile of a frame's pixels mapped to black by the robust rescale (%)."""
    hdr_max_percentile: float = 99.0
    """Percentile of a frame's pixels mapped to white by the robust rescale (%)."""
    hdr_window: int = 10
    """Number of recent frames whose robust bounds are median-filtered (against flicker)."""
    hdr_border: int = 4
    """Border in pixels ignored when computing the robust bounds (networks' edge artefacts)."""
    unsharp_amount: float = 0.0
    """Unsharp-mask strength (0 = off): out = (1 + a) I - a blur(I)."""
    unsharp_sigma: float = 1.0
    """Gaussian sigma of the unsharp mask (pixels)."""
    cutoff_rad_s: float = 5.0
    """highpass - cut-off frequency alpha of the high-pass filter, in rad/s (larger forgets
    faster)."""
    leak_rad_s: float = 0.1
    """integrate - leak rate of direct integration, in rad/s (0 = pure integration, which
    drifts)."""
    contrast_on: float = 0.2
    """Baselines: log-intensity step of one positive event."""
    contrast_off: float = 0.2
    """Baselines: log-intensity step of one negative event."""
    use_conventional_frames: bool = False
    """highpass - complementary filter (Scheerlinck et al. 2018) pulled towards the log of the
    conventional camera's frames (results/{dataset}/conventional/frames) instead of zero."""

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ReconstructConfig:
        """Build from a flat dict of the fields above; unknown keys raise ``ValueError``."""
        return section_from_dict(cls, d, "reconstruct")

    @property
    def is_baseline(self) -> bool:
        return self.method in BASELINES


def resolve_config(section: dict[str, Any], preset: str) -> ReconstructConfig:
    """The config of one preset: the section's shared options, overridden by ``presets[preset]``.

    ``section`` is the ``reconstruct`` section of the workflow config: shared options, a
    ``presets`` map (name -> options, with at least ``method``) and a ``checkpoints`` map
    (method -> weights path) used when a network preset names no ``checkpoint``. A bare method
    name (a baseline, or a key of ``checkpoints``) works as a preset without an entry.
    """
    presets = section.get("presets", {})
    checkpoints = section.get("checkpoints", {})
    if preset in presets:
        options = dict(presets[preset] or {})
    elif preset in BASELINES or preset in checkpoints:
        options = {"method": preset}  # a bare method name needs no preset entry
    else:
        known = sorted(set(presets) | set(checkpoints) | set(BASELINES))
        raise ValueError(f"unknown reconstruct preset {preset!r}; known: {', '.join(known)}")
    d = {k: v for k, v in section.items() if k not in ("presets", "checkpoints", "methods")}
    d.update(options)
    d.setdefault("method", preset)
    conf = ReconstructConfig.from_dict(d)
    if not conf.is_baseline and conf.checkpoint is None:
        conf.checkpoint = checkpoints.get(conf.method)
        if conf.checkpoint is None:
            raise ValueError(
                f"reconstruct preset {preset!r}: network method {conf.method!r} needs a checkpoint "
                "(set reconstruct.checkpoints.<method> or the preset's checkpoint)"
            )
    return conf
