"""Training loop for our FireNet weights: truncated BPTT on simulated sequences, checkpoints, resume.

One training *step* takes a batch of ``batch_size`` random crops (``crop_size`` pixels square) of
``sequence_length`` consecutive windows from random training sequences, runs the network from a
zero state over them in chunks of ``tbptt_length`` windows and makes one optimizer update per
chunk, the recurrent state detached between chunks (truncated backpropagation through time).
With ``reverse_playback`` a crop may run longer than its simulated sequence: the windows play
forward, then backward in time, and so on (:func:`playback_path`).
With ``burn_in_windows`` each crop first runs that many windows without gradient; with
``stream_steps`` a crop lives several steps, its state carried from one to the next
(:class:`CropStreams`).

Inputs are the raw voxel grids with FireNet's input normalisation (non-zero entries of each whole
window standardised to mean 0, std 1, computed over the full frame before cropping, as at
inference). Augmentation: horizontal flips and polarity inversion (negated voxels with target
``1 - target``, exact for our log-domain target).

Every ``checkpoint_every`` steps ``out_dir/checkpoints/step_XXXXXXX.pt`` holds the model, the
optimizer, the sampling RNG and the best validation result, so a stopped run resumes exactly where
it was (bit-identical on the same machine and thread count). Every ``val_every`` steps the
validation split is run at full resolution; when its loss improves, the weights are written in our
checkpoint format (``.pt`` + ``.json``) to ``weights_path`` with their provenance. Losses go to
the log and to ``out_dir/history.jsonl``.
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from evdense.config import section_from_dict
from evdense.formats.files import write_atomic, write_text_atomic
from evdense.log import get_logger
from evdense.recon.checkpoints import infer_architecture, load_checkpoint, save_checkpoint
from evdense.recon.inference import pick_device
from evdense.recon.networks import (
    ReconstructionNet,
    States,
    build_network,
    detach_states,
    zero_states,
)
from evdense.training.data import TrainDataConfig, load_split, read_config, read_seed
from evdense.training.losses import LossWeights, reconstruction_loss, ssim

log = get_logger("training")

CHECKPOINT_FORMAT = "evdense-train-state"


SHAPE_KEYS = ("width", "height", "bins", "windows_per_sequence")
"""``train.data`` keys every set of one run shares (their arrays are stacked into one)."""

MIX_SEED_STRIDE = 1000
"""Entry ``i`` of ``train.mix`` is simulated with the run's seed + this x (i + 1) by default."""


@dataclass
class MixRecipe:
    """One ``train.mix`` entry, resolved against ``train.data``."""

    recipe: TrainDataConfig
    """The whole data recipe of the entry."""
    num_train_sequences: int
    """Training sequences simulated for it."""
    seed: int
    """Seed of its simulation."""


@dataclass
class TrainConfig:
    """Settings of a training run (config section ``train``)."""

    seed: int = 0
    """Seed of the data set, the initial weights and the batch sampling."""
    num_train_sequences: int = 360
    """Simulated training sequences."""
    num_val_sequences: int = 12
    """Simulated validation sequences (training distribution, other seeds; picks the best checkpoint)."""
    num_heldout_sequences: int = 24
    """Simulated held-out sequences (unseen textures, objects, motions, HDR) for the quality table."""
    arch: str = "firenet"
    """Network trained: "firenet" (FireNet: full resolution, ConvGRU, 38 k parameters at 16
    channels) or "e2vid" (an E2VID-class recurrent U-Net with ConvGRU cells and no batch norm:
    each encoder halves the resolution, so it sees far wider context at a similar cost per pixel)."""
    base_channels: int = 16
    """Feature channels (FireNet: at every layer; e2vid: after the head, doubled by each encoder)."""
    num_residual_blocks: int = 2
    """Residual blocks (FireNet: after the head, the first recurrent; e2vid: at the bottleneck)."""
    num_encoders: int = 3
    """e2vid only: stride-2 recurrent encoders (input sides are padded to a multiple of 2**this)."""
    kernel_size: int = 3
    """Kernel of FireNet's head, or of every e2vid head, encoder and decoder convolution."""
    batch_size: int = 4
    """Crops per step."""
    crop_size: int = 64
    """Side of the square training crops, pixels."""
    sequence_length: int = 40
    """Consecutive windows per crop and step (from a zero recurrent state)."""
    tbptt_length: int = 20
    """Windows per backpropagation chunk (the state is detached between chunks)."""
    reverse_playback: bool = False
    """Let ``sequence_length`` exceed the simulated windows: a crop plays its sequence forward,
    then backward in time (each window's voxel bins reversed and polarities negated, the target
    one window earlier), then forward again, and so on, so the recurrent state learns to hold a
    scene over many more windows than were simulated."""
    stream_steps: int = 1
    """Steps a crop lives for. Above 1, each of the ``batch_size`` crops goes on with its sequence
    (played forward and backward, as with ``reverse_playback``) for this many steps, its recurrent
    state carried (detached) from one step to the next, so the loss also sees states up to
    ``stream_steps x sequence_length`` windows old, at the cost of ``sequence_length``; the crops
    are staggered, so each batch mixes young and old states. 1 = a fresh crop from a zero state
    every step."""
    burn_in_windows: int = 0
    """Windows each crop runs before its ``sequence_length``, without gradient, from a zero state
    and with the weights being trained (played forward and backward when the crop runs past its
    sequence, as with ``reverse_playback``), so the loss sees states that many windows older,
    computed by the current weights; costs a forward pass per window (0 = none)."""
    voxel_clip: float = 3.0
    """Cap on ``|voxel|`` before the input normalisation, as ``reconstruct.voxel_clip`` at inference (0 = none)."""
    max_steps: int = 4000
    """Training steps (batches of sequences); the learning rate follows a cosine to this step."""
    lr: float = 2e-3
    """Peak learning rate of Adam."""
    lr_min_fraction: float = 0.05
    """Final learning rate as a fraction of ``lr``."""
    warmup_steps: int = 20
    """Steps of linear learning-rate warm-up."""
    grad_clip: float = 1.0
    """Largest gradient norm (0 = no clipping)."""
    ema_decay: float = 0.0
    """Keep an exponential moving average of the weights with this decay per step (0 = off; 0.995
    averages over about the last 200 steps). When on, validation, the best-weights choice and the
    saved weights use the average; the resumable checkpoints hold both."""
    loss_l1: float = 1.0
    """Weight of the L1 loss."""
    loss_ssim: float = 1.0
    """Weight of the (1 - SSIM) loss."""
    loss_temporal: float = 0.2
    """Weight of the temporal-consistency loss."""
    loss_affine_invariant: bool = False
    """L1, SSIM and temporal terms after each frame's least-squares gain and offset onto its target
    (events fix intensity only up to those; the metric and SfM ignore them)."""
    loss_anchor: float = 0.0
    """Weight of a plain L1 on the raw output, which keeps it in the [0, 1] range of the targets
    when loss_affine_invariant is on."""
    loss_gradient: float = 0.0
    """Weight of a multi-scale gradient-matching loss (L1 of the differences of horizontal and
    vertical finite differences at 1, 1/2, 1/4 and 1/8 resolution; on the aligned frames when
    loss_affine_invariant is on); 0 = off."""
    loss_lowfreq: float = 0.0
    """Weight of an L1 between the 4 x 4 and 8 x 8 block means of prediction and target (the
    large-scale levels, e.g. a plain wall against the floor; on the aligned frames when
    loss_affine_invariant is on); 0 = off."""
    loss_ssim_range: float = 1.0
    """Data range L of the SSIM loss's constants (0.01 L)^2 and (0.03 L)^2, targets being in
    [0, 1]: 1 is the standard SSIM, which stops seeing texture whose local standard deviation is
    below about 0.03; a smaller L makes the loss weigh faint texture (validation's ssim_clipped
    stays the standard SSIM)."""
    loss_perceptual: float = 0.0
    """Weight of a perceptual loss without pretrained weights: LPIPS's distance between unit-
    normalised activations, on a fixed, randomly initialised VGG-shaped network at four scales
    (receptive fields of 5 to about 70 px; Liu et al. 2021 found random networks serve as
    perceptual losses); on the aligned frames when loss_affine_invariant is on; 0 = off."""
    target_power: float = 0.0
    """Tone of the targets: 0 = the stored log-radiance targets (our GT frames' tone); p > 0 =
    radiance to the power p over the same robust range, derived from the stored log radiance at
    load time (1 = linear, as FireNet was trained; 0.45 = about display-encoded). No new data set
    is simulated; the held-out table scores against log and linear GT alike."""
    augment: bool = True
    """Random flips, quarter turns and polarity inversions."""
    augment_rotations: bool = True
    """With ``augment``: random quarter turns of the (square) crops too."""
    checkpoint_every: int = 100
    """Steps between resumable checkpoints."""
    keep_checkpoints: int = 2
    """Resumable checkpoints kept (older ones are deleted)."""
    val_every: int = 100
    """Steps between validations (and best-weights saves)."""
    log_every: int = 20
    """Steps between loss lines in the log."""
    threads: int = 2
    """Torch CPU threads."""
    device: str = "auto"
    """Where to train: ``cpu``, ``cuda`` (or ``cuda:N``) or ``auto`` (CUDA when there is one). The
    data set stays in CPU memory; each batch and the validation split go to the device. A run
    resumes on either (checkpoints are loaded to the CPU first)."""
    time_budget_min: float = 0.0
    """Stop (after a checkpoint and a validation) when training has run this many minutes (0 = no limit)."""
    init_weights: str = ""
    """Start from these weights (ours or a published FireNet of the same shape) instead of a random
    initialisation: a fine-tune, with its own warm-up and cosine schedule ("" = random start)."""
    data: TrainDataConfig = field(default_factory=TrainDataConfig)
    """Recipe of the simulated training set (src/evdense/training/data.py)."""
    mix: list[dict[str, Any]] = field(default_factory=list)
    """Further recipes whose training sequences join those of ``data`` (validation stays on
    ``data``'s split): each entry holds ``num_train_sequences`` (default: the run's) and any
    ``train.data`` keys that differ from ``data`` (a key absent keeps ``data``'s value; the
    camera, the bins and the windows per sequence cannot differ), and optionally ``seed``
    (default: the run's seed + 1000 x (i + 1), so that entry ``i`` draws other scenes and motions
    than the main set). Entry ``i`` is simulated into ``trainset_s<seed>_mix<i>.h5`` (the
    run's seed in the name) beside the main set; each crop of a batch comes from a sequence
    drawn uniformly over all of them, so the recipes weigh as their sequence counts ([] = one
    recipe)."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> TrainConfig:
        """Build from the ``train`` config section; unknown keys raise ``ValueError``."""
        return section_from_dict(cls, d, "train")

    def check(self) -> None:
        if self.sequence_length % self.tbptt_length:
            raise ValueError("train.sequence_length must be a multiple of train.tbptt_length")
        if self.sequence_length > self.data.windows_per_sequence and not self.reverse_playback:
            raise ValueError("train.sequence_length exceeds train.data.windows_per_sequence "
                             "(set train.reverse_playback to play sequences back and forth)")  # fmt: skip
        if self.stream_steps < 1:
            raise ValueError(f"train.stream_steps must be at least 1, not {self.stream_steps}")
        if self.burn_in_windows < 0 or (self.burn_in_windows and self.stream_steps > 1):
            raise ValueError(
                "train.burn_in_windows must be >= 0, and 0 with train.stream_steps > 1"
            )
        if self.crop_size > min(self.data.width, self.data.height):
            raise ValueError("train.crop_size exceeds the simulated camera size")
        if not 0.0 <= self.target_power <= 3.0:
            raise ValueError(f"train.target_power must lie in [0, 3], not {self.target_power}")
        if not 0.0 < self.loss_ssim_range <= 1.0:
            raise ValueError(
                f"train.loss_ssim_range must lie in (0, 1], not {self.loss_ssim_range}"
            )
        if not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"train.ema_decay must lie in [0, 1), not {self.ema_decay}")
        self.mix_recipes()

    def mix_recipes(self) -> list[MixRecipe]:
        """Each ``mix`` entry as its full recipe, number of training sequences and seed."""
        out = []
        for i, entry in enumerate(self.mix):
            where = f"train.mix[{i}]"
            if not isinstance(entry, dict):
                raise ValueError(f"{where}: a mapping of train.data keys, not {entry!r}")
            entry = dict(entry)
            n = entry.pop("num_train_sequences", self.num_train_sequences)
            seed = entry.pop("seed", self.seed + MIX_SEED_STRIDE * (i + 1))
            for key, v, low in (("num_train_sequences", n, 1), ("seed", seed, 0)):
                if isinstance(v, bool) or not float(v).is_integer() or v < low:
                    raise ValueError(f"{where}.{key} must be an integer >= {low}, not {v!r}")
            changed = [k for k in SHAPE_KEYS if k in entry and entry[k] != getattr(self.data, k)]
            if changed:
                raise ValueError(f"{where}: {', '.join(changed)} must equal train.data's")
            try:
                recipe = section_from_dict(TrainDataConfig, {**asdict(self.data), **entry}, where)
            except ValueError as e:  # the recipe's own checks name train.data
                msg = str(e)
                if msg.startswith("train.data"):
                    msg = where + msg.removeprefix("train.data")
                raise ValueError(msg) from None
            out.append(MixRecipe(recipe, int(n), int(seed)))
        return out

    def splits(self) -> dict[str, int]:
        """Split name -> number of sequences to simulate."""
        return {
            "train": self.num_train_sequences,
            "val": self.num_val_sequences,
            "heldout": self.num_heldout_sequences,
        }

    def loss_weights(self) -> LossWeights:
        return LossWeights(
            self.loss_l1,
            self.loss_ssim,
            self.loss_temporal,
            self.loss_affine_invariant,
            self.loss_anchor,
            self.loss_gradient,
            self.loss_lowfreq,
            self.loss_ssim_range,
            self.loss_perceptual,
        )


@dataclass
class TrainResult:
    """What a run produced."""

    weights_path: Path
    """Best-validation weights (our format; the JSON beside it)."""
    step: int
    """Last step trained."""
    best_step: int
    """Step of the best validation loss."""
    best_val: dict[str, float]
    """Validation metrics at the best step."""
    train_seconds: float
    """Wall time spent training (all sessions of a resumed run), seconds."""


# ---------------------------------------------------------------------------------------------
# Data in memory
# ---------------------------------------------------------------------------------------------


def normalize_windows(voxels: np.ndarray, clip: float = 0.0) -> torch.Tensor:
    """FireNet's input normalisation per window, ``(..., B, H, W)`` -> float16 tensor, same shape.

    Each cell is first capped at ``|v| <= clip`` (0 = no cap), then the non-zero entries of each
    window are standardised to mean 0 and (unbiased) std 1, zeros stay zero (as
    :class:`evdense.recon.inference.NetworkReconstructor` does at inference).
    """
    shape = voxels.shape
    flat = voxels.reshape(-1, int(np.prod(shape[-3:])))
    out = torch.empty(flat.shape, dtype=torch.float16)
    for i in range(0, len(flat), 64):
        x = torch.from_numpy(np.asarray(flat[i : i + 64], dtype=np.float32))
        if clip > 0:
            x = x.clamp(-clip, clip)
        mask = x != 0
        n = mask.sum(1, keepdim=True).clamp_min(1)
        mean = x.sum(1, keepdim=True) / n
        var = ((x - mean) ** 2 * mask).sum(1, keepdim=True) / (n - 1).clamp_min(1)
        std = var.sqrt()
        std = torch.where(std > 0, std, torch.ones_like(std))
        out[i : i + 64] = torch.where(mask, (x - mean) / std, torch.zeros_like(x)).half()
    return out.reshape(shape)


def playback_path(
    num_windows: int, start: int, length: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Windows, targets and the played-backward mask of ``length`` steps of a sequence of
    ``num_windows`` windows played forward, backward, forward... from position ``start`` of the
    cycle (``0 <= start < 2 (num_windows - 1)``).

    Window ``i`` spans ``(T_i, T_i+1]`` and its target is the frame at ``T_i+1``. Played backward,
    the same events run from ``T_i+1`` to ``T_i``: in a bilinear-in-time voxel grid that is the
    bins in reverse order with negated polarities (also after the input normalisation, which is odd
    in the voxels), and its target is the frame at ``T_i``, window ``i - 1``'s. The cycle plays
    windows ``1 .. n-1`` forward, then ``n-1 .. 1`` backward (targets ``n-2 .. 0``); window 0,
    whose start frame is not stored, is left out.
    """
    if num_windows < 2:
        raise ValueError("reverse playback needs sequences of at least 2 windows")
    period = 2 * (num_windows - 1)
    pos = (start + np.arange(length)) % period
    back = pos >= num_windows - 1
    win = np.where(back, period - pos, pos + 1)
    tgt = np.where(back, win - 1, win)
    return torch.from_numpy(win), torch.from_numpy(tgt), torch.from_numpy(back)


class SequenceSampler:
    """Random crops of consecutive windows from a split held in memory (float16)."""

    def __init__(self, voxels: np.ndarray, targets: np.ndarray, conf: TrainConfig) -> None:
        self.voxels = normalize_windows(voxels, conf.voxel_clip)  # (S, W, B, H, Wd)
        self.targets = torch.from_numpy(np.asarray(targets, dtype=np.float16))  # (S, W, H, Wd)
        self.conf = conf

    def draw_view(self, rng: np.random.Generator) -> tuple[int, int, bool, bool, int]:
        """A crop's corner and augmentation: ``(y0, x0, flip, invert, quarter turns)``."""
        c = self.conf.crop_size
        _, _, _, h, w = self.voxels.shape
        y0 = int(rng.integers(0, h - c + 1))
        x0 = int(rng.integers(0, w - c + 1))
        flip, invert = rng.random(2) < 0.5
        q = 0
        if self.conf.augment and self.conf.augment_rotations:
            q = int(rng.integers(4))
        return y0, x0, bool(flip), bool(invert), q

    def crop(
        self,
        s: int,
        win: slice | torch.Tensor,
        tgt: slice | torch.Tensor,
        back: torch.Tensor | None,
        view: tuple[int, int, bool, bool, int],
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Voxels ``(L, B, c, c)`` and targets ``(L, 1, c, c)`` of sequence ``s``'s windows ``win``
        (targets ``tgt``, those in ``back`` played backward) seen through ``view``."""
        c = self.conf.crop_size
        y0, x0, flip, invert, q = view
        v = self.voxels[s, win, :, y0 : y0 + c, x0 : x0 + c].float()
        if back is not None:
            v[back] = -v[back].flip(1)
        t = self.targets[s, tgt, y0 : y0 + c, x0 : x0 + c].float()
        if self.conf.augment and flip:
            v, t = v.flip(-1), t.flip(-1)
        if self.conf.augment and invert:
            v, t = -v, 1.0 - t
        if q:
            v, t = v.rot90(q, (-2, -1)), t.rot90(q, (-2, -1))
        return v, t[:, None]

    def batch(self, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Voxels ``(L, N, B, c, c)`` and targets ``(L, N, 1, c, c)`` float32 for one step
        (``L`` = ``burn_in_windows + sequence_length``)."""
        L = self.conf.burn_in_windows + self.conf.sequence_length
        s_all, w_all = self.voxels.shape[:2]
        xs, ys = [], []
        for _ in range(self.conf.batch_size):
            s = int(rng.integers(s_all))
            if L <= w_all:  # consecutive windows as simulated
                k = int(rng.integers(0, w_all - L + 1))
                win = tgt = slice(k, k + L)
                back = None
            else:
                win, tgt, back = playback_path(w_all, int(rng.integers(0, 2 * (w_all - 1))), L)
            v, t = self.crop(s, win, tgt, back, self.draw_view(rng))
            xs.append(v)
            ys.append(t)
        return torch.stack(xs, 1).contiguous(), torch.stack(ys, 1).contiguous()


class CropStreams:
    """``batch_size`` crops that each live ``train.stream_steps`` steps (``stream_steps`` > 1).

    A stream is a sequence, a playback position and a view (corner and augmentation). Each step
    it gives its next ``sequence_length`` windows, played forward and backward through the
    simulated ones (:func:`playback_path`), and the caller carries its recurrent state over, so
    the loss sees states up to ``stream_steps x sequence_length`` windows old at the cost of
    ``sequence_length``. Streams start staggered (stream ``i`` first lives
    ``1 + i * stream_steps // batch_size`` steps), so every batch mixes young and old states.
    """

    def __init__(self, sampler: SequenceSampler) -> None:
        self.sampler = sampler
        n = sampler.conf.batch_size
        # per stream: sequence (-1 = none yet), cycle position, steps left (0 = draw anew), view
        self.seq = [-1] * n
        self.pos = [0] * n
        self.left = [0] * n
        self.views: list[tuple[int, int, bool, bool, int]] = [(0, 0, False, False, 0)] * n

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint keeps to continue the streams exactly."""
        return {"seq": self.seq, "pos": self.pos, "left": self.left, "views": self.views}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        self.seq, self.pos, self.left = list(d["seq"]), list(d["pos"]), list(d["left"])
        self.views = [tuple(v) for v in d["views"]]  # type: ignore[misc]

    def batch(self, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Voxels ``(L, N, B, c, c)``, targets ``(L, N, 1, c, c)`` and a bool ``(N,)``: the streams
        that start this step (their state must start from zero)."""
        sp = self.sampler
        n, k, L = len(self.seq), sp.conf.stream_steps, sp.conf.sequence_length
        s_all, w_all = sp.voxels.shape[:2]
        period = 2 * (w_all - 1)
        fresh = torch.zeros(n, dtype=torch.bool)
        xs, ys = [], []
        for i in range(n):
            if self.left[i] == 0:
                self.left[i] = 1 + i * k // n if self.seq[i] < 0 else k  # first lives staggered
                self.seq[i] = int(rng.integers(s_all))
                self.pos[i] = int(rng.integers(0, period))
                self.views[i] = sp.draw_view(rng)
                fresh[i] = True
            win, tgt, back = playback_path(w_all, self.pos[i], L)
            v, t = sp.crop(self.seq[i], win, tgt, back, self.views[i])
            self.pos[i] = (self.pos[i] + L) % period
            self.left[i] -= 1
            xs.append(v)
            ys.append(t)
        return torch.stack(xs, 1).contiguous(), torch.stack(ys, 1).contiguous(), fresh


# ---------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------


@torch.no_grad()
def validate(
    net: ReconstructionNet, voxels: torch.Tensor, targets: torch.Tensor, weights: LossWeights
) -> dict[str, float]:
    """Run ``net`` over whole validation sequences from a zero state; mean loss terms and SSIM.

    ``voxels``: normalised ``(S, W, B, H, Wd)``; ``targets``: ``(S, W, H, Wd)``. The loss is the
    training loss over chunks of all windows; ``ssim_clipped`` is the SSIM of the clipped output.
    """
    net.eval()
    states = None
    preds = []
    for k in range(voxels.shape[1]):
        img, states = net(voxels[:, k].float(), states)
        preds.append(img)
    net.train()
    pred = torch.stack(preds)  # (W, S, 1, H, Wd)
    tgt = targets.float().transpose(0, 1)[:, :, None]
    _, terms = reconstruction_loss(pred, tgt, weights)
    w, s = pred.shape[:2]
    terms["ssim_clipped"] = float(
        ssim(
            pred.clamp(0, 1).reshape(w * s, 1, *pred.shape[3:]),
            tgt.reshape(w * s, 1, *tgt.shape[3:]),
        )
    )
    return terms


# ---------------------------------------------------------------------------------------------
# Checkpoints
# ---------------------------------------------------------------------------------------------


def _checkpoint_dir(out_dir: Path) -> Path:
    return out_dir / "checkpoints"


def latest_checkpoint(out_dir: str | Path) -> Path | None:
    """The resumable checkpoint with the highest step in ``out_dir/checkpoints``, or None."""
    d = _checkpoint_dir(Path(out_dir))
    found = sorted(d.glob("step_*.pt")) if d.is_dir() else []
    return found[-1] if found else None


def _save_state(out_dir: Path, state: dict[str, Any], keep: int) -> Path:
    d = _checkpoint_dir(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"step_{state['step']:07d}.pt"
    write_atomic(path, lambda tmp: torch.save(state, tmp))
    for old in sorted(d.glob("step_*.pt"))[:-keep]:
        old.unlink()
    return path


def _load_state(path: Path) -> dict[str, Any]:
    state = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not an evdense training checkpoint")
    return state


def _lr_at(step: int, conf: TrainConfig, spent_s: float = 0.0) -> float:
    """Linear warm-up, then a cosine from ``lr`` to ``lr * lr_min_fraction``.

    The cosine's progress is the fraction of ``max_steps`` done, or, with a time budget, the
    fraction of the budget spent when that is larger (so a run cut by the budget still ends at a
    low learning rate; such a run is not bit-reproducible, as it depends on the machine's speed).
    """
    if step < conf.warmup_steps:
        return conf.lr * (step + 1) / conf.warmup_steps
    span = max(1, conf.max_steps - conf.warmup_steps)
    u = (step - conf.warmup_steps) / span
    if conf.time_budget_min > 0:
        u = max(u, spent_s / (conf.time_budget_min * 60))
    u = min(1.0, u)
    lo = conf.lr * conf.lr_min_fraction
    return lo + 0.5 * (conf.lr - lo) * (1 + math.cos(math.pi * u))


# ---------------------------------------------------------------------------------------------
# The run
# ---------------------------------------------------------------------------------------------


def describe_device(dev: torch.device) -> str:
    """``cpu (N threads)`` or ``cuda:0 (NVIDIA H200)``, for the log and the weights' provenance."""
    if dev.type == "cuda":
        return f"{dev} ({torch.cuda.get_device_name(dev)})"
    return f"{dev} ({torch.get_num_threads()} threads)"


def model_hparams(conf: TrainConfig) -> dict[str, Any]:
    """Constructor arguments of the run's ``conf.arch`` network."""
    hp: dict[str, Any] = dict(
        num_bins=conf.data.bins,
        base_channels=conf.base_channels,
        num_residual_blocks=conf.num_residual_blocks,
        kernel_size=conf.kernel_size,
    )
    if conf.arch == "e2vid":
        hp.update(num_encoders=conf.num_encoders, norm="none", recurrent_block_type="convgru")
    elif conf.arch != "firenet":
        raise ValueError(f"train.arch must be 'firenet' or 'e2vid', not {conf.arch!r}")
    return hp


def build_model(conf: TrainConfig, init: bool = True) -> ReconstructionNet:
    """The ``conf.arch`` network with the run's hyper-parameters, initialised from ``conf.seed``,
    or (``init``) with the weights of ``conf.init_weights`` when set (same architecture)."""
    torch.manual_seed(conf.seed)
    net = build_network(conf.arch, **model_hparams(conf))
    if init and conf.init_weights:
        loaded = load_checkpoint(conf.init_weights)
        try:
            net.load_state_dict(loaded.net.state_dict(), strict=True)
        except RuntimeError as e:
            raise ValueError(
                f"train.init_weights {conf.init_weights}: {loaded.arch} {loaded.hparams} does not "
                f"fit the run's {conf.arch} {model_hparams(conf)}: {e}"
            ) from None
        log.info("initial weights from %s", conf.init_weights)
    return net


def _train_step(
    net: ReconstructionNet,
    opt: torch.optim.Optimizer,
    x: torch.Tensor,
    y: torch.Tensor,
    conf: TrainConfig,
    weights: LossWeights,
    states: States | None = None,
) -> tuple[list[dict[str, float]], States | None]:
    """One step on a batch (voxels ``x`` ``(L, N, B, c, c)``, targets ``y``): the network runs
    from ``states`` (None: zeros) over the ``L`` windows, one optimizer update per chunk of
    ``tbptt_length`` windows, the state detached between chunks. Returns each chunk's loss terms
    and the detached state after the last window. The first ``conf.burn_in_windows`` windows
    run without gradient and without loss."""
    out = []
    b = conf.burn_in_windows
    if b:
        with torch.no_grad():
            for k in range(b):
                _, states = net(x[k].contiguous(memory_format=torch.channels_last), states)
    for c0 in range(b, b + conf.sequence_length, conf.tbptt_length):
        preds = []
        for k in range(c0, c0 + conf.tbptt_length):
            img, states = net(x[k].contiguous(memory_format=torch.channels_last), states)
            preds.append(img)
        loss, terms = reconstruction_loss(
            torch.stack(preds), y[c0 : c0 + conf.tbptt_length], weights
        )
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if conf.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(net.parameters(), conf.grad_clip)
        opt.step()
        states = detach_states(states)
        out.append(terms)
    return out, states


@torch.no_grad()
def update_ema(ema: ReconstructionNet, net: ReconstructionNet, decay: float, step: int) -> None:
    """Move ``ema``'s weights towards ``net``'s: ``ema = d ema + (1 - d) net`` with
    ``d = min(decay, (1 + step) / (10 + step))``, so the first steps are not dominated by the start."""
    d = min(decay, (1 + step) / (10 + step))
    for pe, p in zip(ema.parameters(), net.parameters(), strict=True):
        pe.lerp_(p, 1.0 - d)
    for be, b in zip(ema.buffers(), net.buffers(), strict=True):
        be.copy_(b)


# Over 80 lines on purpose: the run's resumable state (step, best loss and step, RNG, time spent)
# lives in these locals, which save_state() writes and the resume block restores; the step itself
# is _train_step and the validation validate().
def train_model(
    conf: TrainConfig,
    data_path: str | Path,
    out_dir: str | Path,
    weights_path: str | Path,
    resume: bool = True,
    max_steps: int | None = None,
    mix_paths: Sequence[str | Path] = (),
) -> TrainResult:
    """Train FireNet on the simulated set ``data_path`` (see :func:`~evdense.training.data.generate_dataset`).

    ``mix_paths``: further sets (``train.mix``) whose training sequences join those of
    ``data_path``; validation uses ``data_path``'s. Resumes from the latest checkpoint in
    ``out_dir/checkpoints`` when ``resume``; ``max_steps`` stops this session early (the
    schedule still follows ``conf.max_steps``), for tests and for splitting a run.
    Best-validation weights go to ``weights_path`` (``.pt`` + ``.json``).
    """
    out_dir, weights_path = Path(out_dir), Path(weights_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(conf.threads)
    dev = pick_device(conf.device)
    data_conf = read_config(data_path)
    mix_confs = [read_config(m) for m in mix_paths]
    for path, dc in [(data_path, data_conf), *zip(mix_paths, mix_confs, strict=True)]:
        if any(getattr(dc, k) != getattr(conf.data, k) for k in SHAPE_KEYS):
            raise ValueError(f"{path}: made with another camera, bin count or windows per "
                             "sequence than train.data")  # fmt: skip
    weights = conf.loss_weights()
    tone = conf.target_power if conf.target_power else None  # None: the stored targets
    t_vox, t_tgt = load_split(data_path, "train", tone)
    if mix_paths:
        parts = [(t_vox, t_tgt), *(load_split(m, "train", tone) for m in mix_paths)]
        t_vox = np.concatenate([v for v, _ in parts])
        t_tgt = np.concatenate([t for _, t in parts])
        log.info("training sequences: %s", " + ".join(str(len(v)) for v, _ in parts))
        del parts
    train = SequenceSampler(t_vox, t_tgt, conf)
    streams = CropStreams(train) if conf.stream_steps > 1 else None
    stream_states: States | None = None
    del t_vox, t_tgt
    v_vox, v_tgt = load_split(data_path, "val", tone)
    v_vox = normalize_windows(v_vox, conf.voxel_clip).to(dev)
    v_tgt = torch.from_numpy(v_tgt).to(dev)

    ckpt = latest_checkpoint(out_dir) if resume else None
    cl = torch.channels_last  # faster convolutions on CPU (oneDNN) and on CUDA (cuDNN NHWC)
    net = build_model(conf, init=ckpt is None).to(device=dev, memory_format=cl)
    log.info("training on %s", describe_device(dev))
    net.train()
    ema = copy.deepcopy(net) if conf.ema_decay > 0 else None
    judged = net if ema is None else ema  # what is validated and saved
    opt = torch.optim.Adam(net.parameters(), lr=conf.lr)
    rng = np.random.default_rng(conf.seed)
    step, best_loss, best_step, best_val, spent = 0, math.inf, -1, {}, 0.0
    history = out_dir / "history.jsonl"
    if ckpt is not None:
        state = _load_state(ckpt)
        net.load_state_dict(state["model"])
        if ema is not None:
            if "ema" not in state:
                raise ValueError(
                    f"{ckpt}: made without train.ema_decay; resume it without the option"
                )
            ema.load_state_dict(state["ema"])
        opt.load_state_dict(state["optimizer"])
        rng.bit_generator.state = json.loads(state["rng"])
        step, best_loss, best_step = state["step"], state["best_loss"], state["best_step"]
        best_val, spent = json.loads(state["best_val"]), state["train_seconds"]
        if streams is not None:
            if "streams" not in state:
                raise ValueError(f"{ckpt}: made without train.stream_steps; resume it without it")
            streams.load_state_dict(json.loads(state["streams"]))
            # trained networks are GRU-recurrent: one tensor per recurrent layer
            stream_states = [t.to(dev) for t in state["stream_states"]] or None
        log.info("resumed from %s (step %d)", ckpt, step)
        if history.is_file():  # drop lines written after that checkpoint
            lines = [ln for ln in history.read_text().splitlines() if ln.strip()]
            kept = [ln for ln in lines if json.loads(ln)["step"] <= step]
            history.write_text("".join(ln + "\n" for ln in kept))
    elif history.is_file():
        history.unlink()

    mix_record = [
        {"data_file": str(m), "seed": read_seed(m), "data_recipe": asdict(dc)}
        for m, dc in zip(mix_paths, mix_confs, strict=True)
    ]
    provenance_base = {
        "trained_by": "evdense.training.train.train_model",
        "train_config": asdict(conf),
        "data_file": str(data_path),
        "data_recipe": asdict(data_conf),
        **({"mix": mix_record} if mix_record else {}),
        "seed": conf.seed,
        "device": describe_device(dev),
        "target": ("log radiance" if not conf.target_power else f"radiance ** {conf.target_power}")
        + " at the window end, per-sequence robust range "
        f"(log-radiance percentiles {data_conf.target_percentiles}) mapped to [0, 1]",
        "input_normalization": "nonzero (non-zero voxels of each window to mean 0, std 1)",
    }

    def save_state() -> None:
        _save_state(
            out_dir,
            {
                "format": CHECKPOINT_FORMAT,
                "step": step,
                "model": net.state_dict(),
                **({} if ema is None else {"ema": ema.state_dict()}),
                "optimizer": opt.state_dict(),
                "rng": json.dumps(rng.bit_generator.state),
                "best_loss": best_loss,
                "best_step": best_step,
                "best_val": json.dumps(best_val),
                "train_seconds": spent,
                **(
                    {}
                    if streams is None
                    else {
                        "streams": json.dumps(streams.state_dict()),
                        "stream_states": [t.cpu() for t in stream_states or []],
                    }
                ),
            },
            conf.keep_checkpoints,
        )

    def write_history(rec: dict[str, Any]) -> None:
        with history.open("a") as f:
            f.write(json.dumps(rec) + "\n")

    stop = conf.max_steps if max_steps is None else min(conf.max_steps, max_steps)
    t_session = time.monotonic()
    spent0 = spent
    running: dict[str, float] = {}
    while step < stop:
        lr = _lr_at(step, conf, spent)
        for g in opt.param_groups:
            g["lr"] = lr
        if streams is None:
            x, y = train.batch(rng)
            start = None
        else:  # each stream goes on from its state; those that start anew from zeros
            x, y, fresh = streams.batch(rng)
            start = zero_states(stream_states, fresh.to(dev))
        x, y = x.to(dev, non_blocking=True), y.to(dev, non_blocking=True)
        terms_list, end = _train_step(net, opt, x, y, conf, weights, start)
        if streams is not None:
            stream_states = end
        for terms in terms_list:
            for key, v in terms.items():
                running[key] = running.get(key, 0.0) + v
        if ema is not None:
            update_ema(ema, net, conf.ema_decay, step)
        step += 1
        spent = spent0 + time.monotonic() - t_session
        if step % conf.log_every == 0 or step == stop:
            n = len(range(0, conf.sequence_length, conf.tbptt_length)) * (
                conf.log_every if step % conf.log_every == 0 else step % conf.log_every
            )
            avg = {k: v / n for k, v in running.items()}
            running = {}
            log.info(
                "step %d/%d lr %.2e loss %.4f (l1 %.4f ssim %.4f temporal %.4f) %.0f s",
                step, conf.max_steps, lr, avg["loss"], avg["l1"], avg["ssim"], avg["temporal"], spent,
            )  # fmt: skip
            write_history({"step": step, "lr": lr, "train": avg, "seconds": spent})
        out_of_time = conf.time_budget_min > 0 and spent > conf.time_budget_min * 60
        last = step == stop or out_of_time
        if step % conf.val_every == 0 or last:
            val = validate(judged, v_vox, v_tgt, weights)
            write_history({"step": step, "val": val, "seconds": spent})
            log.info(
                "step %d validation loss %.4f ssim %.4f", step, val["loss"], val["ssim_clipped"]
            )
            if val["loss"] < best_loss:
                best_loss, best_step, best_val = val["loss"], step, val
                save_checkpoint(
                    judged,
                    weights_path,
                    {**provenance_base, "step": step, "validation": val, "train_seconds": spent},
                )
                log.info("step %d: new best validation loss, weights -> %s", step, weights_path)
        if step % conf.checkpoint_every == 0 or last:
            save_state()
        if out_of_time:
            log.info("time budget of %.1f min reached at step %d", conf.time_budget_min, step)
            break
    return TrainResult(weights_path, step, best_step, best_val, spent)


def export_state_weights(
    state_path: str | Path, out_path: str | Path, averaged: bool = False
) -> Path:
    """Write the weights held in a resumable checkpoint (``RUN/checkpoints/step_*.pt``) in our
    weights format (``.pt`` + ``.json``): the trained weights, or (``averaged``) the moving average
    kept by a run with ``train.ema_decay``. The provenance names the checkpoint and its step."""
    state_path = Path(state_path)
    state = _load_state(state_path)
    key = "ema" if averaged else "model"
    if key not in state:
        raise ValueError(
            f"{state_path}: holds no averaged weights (trained without train.ema_decay)"
        )
    arch, hparams = infer_architecture(state[key])
    net = build_network(arch, **hparams)
    net.load_state_dict(state[key], strict=True)
    info = {"exported_from": str(state_path), "step": state["step"], "weights": key}
    return save_checkpoint(net, out_path, info)


def update_provenance(weights_path: str | Path, extra: dict[str, Any]) -> None:
    """Add ``extra`` to the provenance in the JSON beside ``weights_path`` (rewritten atomically)."""
    meta_path = Path(weights_path).with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta.setdefault("provenance", {}).update(extra)
    write_text_atomic(meta_path, json.dumps(meta, indent=2, default=str) + "\n")
