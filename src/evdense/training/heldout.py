"""Quality of reconstruction methods on held-out simulated sequences (the quality table).

Every method sees the same windows of every held-out sequence of a training set (see
:mod:`evdense.training.data`), from an empty state at the sequence start:

- networks (our weights, published FireNet, FireNet+, any checkpoint
  :func:`evdense.recon.checkpoints.load_checkpoint` reads) run through
  :class:`evdense.recon.inference.NetworkReconstructor` on the raw voxel grids, each with its own
  input normalisation, output clipped to [0, 1] as in the pipeline;
- ``highpass`` and ``integrate``: :class:`evdense.recon.baselines.LogIntensityFilter` on the
  events, given the sequence's nominal contrast thresholds (an oracle the networks do not get).

Metric normalisation, the same for all methods: each predicted frame and each GT frame is
rescaled by its own robust min/max (``low_percentile``/``high_percentile``, clipped to [0, 1];
:func:`evdense.evaluate.images.normalize_intensity`) before MSE and SSIM
(:func:`evdense.evaluate.images.image_metrics`), so neither a global gain/offset nor the unknown
absolute brightness of events counts. Two GT references: ``log`` (log radiance, as our GT frames
are tone-mapped and as our network is trained) and ``linear`` (linear radiance, closer to what the
published networks were trained to output). The first ``skip_windows`` windows of each sequence
(state warm-up) are left out.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from evdense.evaluate.images import image_metrics, normalize_intensity
from evdense.events.container import Events
from evdense.log import get_logger
from evdense.recon.baselines import LogIntensityFilter
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.inference import NetworkReconstructor

log = get_logger("training")

BASELINE_METHODS = ("highpass", "integrate")


@dataclass
class EvalConfig:
    """How the quality table is computed (config section ``train.evaluate``)."""

    skip_windows: int = 5
    """Windows at the start of each sequence left out of the metrics (recurrent-state warm-up)."""
    low_percentile: float = 1.0
    """Per-frame robust min: this percentile of a frame maps to 0 before MSE/SSIM (%)."""
    high_percentile: float = 99.0
    """Per-frame robust max: this percentile of a frame maps to 1 before MSE/SSIM (%)."""
    highpass_cutoff_rad_s: float = 5.0
    """Cut-off frequency of the high-pass filter baseline (rad/s)."""
    integrate_leak_rad_s: float = 0.1
    """Leak of the direct-integration baseline (rad/s)."""
    voxel_clip: float = 3.0
    """Cap on ``|voxel|`` before a network's input normalisation (the pipeline's ``reconstruct.voxel_clip``)."""


@dataclass
class HeldoutSequence:
    """One held-out sequence as read from the training-set file."""

    name: str
    voxels: np.ndarray
    """(W, B, H, Wd) float32 raw voxel grids."""
    targets: np.ndarray
    """(W, H, Wd) float32 log-radiance targets in [0, 1]."""
    log_radiance: np.ndarray
    """(W, H, Wd) float32 log radiance at the window ends."""
    t_end_us: np.ndarray
    """(W,) int64 window end times, microseconds."""
    events: Events
    window_index: np.ndarray
    """(W + 1,) event index of each window start."""
    recipe: dict[str, Any]


def read_heldout(path: str | Path, split: str = "heldout") -> list[HeldoutSequence]:
    """The sequences of ``split`` with their events (``ValueError`` when missing)."""
    out = []
    with h5py.File(path, "r") as f:
        if split not in f:
            raise ValueError(f"{path}: no {split!r} split")
        for name in sorted(f[split]):
            g = f[split][name]
            if "events" not in g:
                raise ValueError(f"{path}: {split}/{name} has no events (baselines need them)")
            e = g["events"]
            out.append(
                HeldoutSequence(
                    name=name,
                    voxels=g["voxels"][()].astype(np.float32),
                    targets=g["targets"][()].astype(np.float32),
                    log_radiance=g["log_radiance"][()].astype(np.float32),
                    t_end_us=g["t_end_us"][()],
                    events=Events(e["t"][()], e["x"][()], e["y"][()], e["p"][()]),
                    window_index=g["window_index"][()],
                    recipe=json.loads(g.attrs["recipe"]),
                )
            )
    return out


def baseline_frames(seq: HeldoutSequence, method: str, conf: EvalConfig) -> np.ndarray:
    """Log-intensity frames ``(W, H, Wd)`` of a baseline at the window ends."""
    cam = seq.recipe["event_camera"]
    cutoff = conf.highpass_cutoff_rad_s if method == "highpass" else conf.integrate_leak_rad_s
    _, h, w = seq.targets.shape
    ev = seq.events
    filt = LogIntensityFilter(
        h, w, cutoff, cam["contrast_pos"], cam["contrast_neg"], t_us=int(ev.t[0]) - 1
    )
    frames = np.zeros(seq.targets.shape, np.float32)
    for k in range(len(seq.targets)):
        a, b = seq.window_index[k], seq.window_index[k + 1]
        frames[k] = filt.advance(ev[a:b], int(seq.t_end_us[k]))
    return frames


def method_frames(
    seq: HeldoutSequence, method: str, checkpoint: str | None, conf: EvalConfig
) -> np.ndarray:
    """Frames ``(W, H, Wd)`` of one method (a baseline name, or a network given by ``checkpoint``)."""
    if method in BASELINE_METHODS:
        return baseline_frames(seq, method, conf)
    if checkpoint is None:
        raise ValueError(f"method {method!r} is no baseline and has no checkpoint")
    rec = NetworkReconstructor(load_checkpoint(checkpoint).net, voxel_clip=conf.voxel_clip)
    return rec.run(seq.voxels)


def frame_scores(pred: np.ndarray, gt: np.ndarray, conf: EvalConfig) -> dict[str, float]:
    """MSE and SSIM of one frame against GT, both rescaled per frame by their robust min/max."""
    p = normalize_intensity(pred, conf.low_percentile, conf.high_percentile)
    g = normalize_intensity(gt, conf.low_percentile, conf.high_percentile)
    m = image_metrics(p, g)
    return {"mse": m["mse"], "ssim": m["ssim"]}


def evaluate_methods(
    data_path: str | Path,
    methods: dict[str, str | None],
    conf: EvalConfig | None = None,
    split: str = "heldout",
) -> list[dict[str, Any]]:
    """Score every method on every held-out sequence; one row per method.

    ``methods``: name -> checkpoint path for networks, or None for the baselines ``highpass`` and
    ``integrate``. Each row has ``method``, ``mse``/``ssim`` (against log GT), ``mse_linear``/
    ``ssim_linear`` (against linear GT), ``ssim_<kind>`` per sequence kind (smooth, fast, shake,
    hdr) and ``frames`` (frames scored).
    """
    conf = conf or EvalConfig()
    seqs = read_heldout(data_path, split)
    rows = []
    for method, ckpt in methods.items():
        scores: dict[str, list[float]] = {}
        for seq in seqs:
            frames = method_frames(seq, method, ckpt, conf)
            kind = seq.recipe.get("kind", "smooth")
            for k in range(conf.skip_windows, len(frames)):
                s_log = frame_scores(frames[k], seq.targets[k], conf)
                s_lin = frame_scores(frames[k], np.exp(seq.log_radiance[k]), conf)
                for key, v in (
                    ("mse", s_log["mse"]),
                    ("ssim", s_log["ssim"]),
                    ("mse_linear", s_lin["mse"]),
                    ("ssim_linear", s_lin["ssim"]),
                    (f"ssim_{kind}", s_log["ssim"]),
                ):
                    scores.setdefault(key, []).append(v)
        row: dict[str, Any] = {"method": method}
        row.update({k: float(np.mean(v)) for k, v in scores.items()})
        row["frames"] = len(scores.get("ssim", []))
        rows.append(row)
        log.info("%s: SSIM %.3f MSE %.4f", method, row.get("ssim", np.nan), row.get("mse", np.nan))
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    """The rows of :func:`evaluate_methods` as a Markdown table."""
    kinds = [
        k
        for k in ("ssim_smooth", "ssim_fast", "ssim_shake", "ssim_hdr")
        if any(k in r for r in rows)
    ]
    cols = ["mse", "ssim", "mse_linear", "ssim_linear", *kinds, "frames"]
    head = "| method | " + " | ".join(cols) + " |"
    sep = "|---" * (len(cols) + 1) + "|"
    lines = [head, sep]
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c)
            cells.append("-" if v is None else str(v) if c == "frames" else f"{v:.4f}")
        lines.append(f"| {r['method']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
