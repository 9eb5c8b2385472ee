"""Losses for training a reconstruction network: L1, SSIM and a temporal-consistency term.

All take predictions and targets ``(N, 1, H, W)`` (or a stack ``(T, N, 1, H, W)`` for the
temporal term) in target units ([0, 1]) and return a scalar tensor.

Events fix intensity only up to a gain and an offset per pixel history, and neither the quality
metric (each frame rescaled by its robust range) nor SfM cares about a global gain and offset of
a frame. With ``LossWeights.affine_invariant`` the L1 and SSIM terms are computed after the least-
squares gain and offset of each predicted frame onto its target (:func:`affine_align`), so that
training spends its signal on structure rather than on guessing brightness; a plain L1 with the
small weight ``anchor`` keeps the raw output in the target's [0, 1] range (the pipeline clips it).

``LossWeights.gradient`` adds a multi-scale gradient-matching term (the L1 of the difference of
the horizontal and vertical finite differences of prediction and target at 1, 1/2, 1/4 and 1/8
resolution, as in the scale-invariant depth losses of MiDaS, Ranftl et al. 2020): it rewards
edges in the right place at every scale, which pixel L1 and an 11-px SSIM weigh little on flat
regions; on the affine-aligned frames when ``affine_invariant`` is on. ``LossWeights.lowfreq`` adds
the L1 between 4 x 4 and 8 x 8 block means of prediction and target (:func:`lowfreq_l1`): it
weighs the large-scale levels (a plain wall against the floor beside it) that the SSIM window and
the texture-dominated pixel L1 leave to chance. It is aimed at a network that renders fine texture
with a high gain and the steps between large plain regions with a low one; a short fine-tune at
weights 2 and 8 did not change that (the ablation table in docs/benchmarks.md).
``LossWeights.ssim_range`` gives the SSIM term the constants of a smaller data range, so that it
weighs texture too faint for the standard SSIM (on the real clips a trade, not a gain: same table).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

_SSIM_C1 = 0.01**2
_SSIM_C2 = 0.03**2


def _gaussian_window(size: int, sigma: float, dtype: torch.dtype) -> Tensor:
    x = torch.arange(size, dtype=dtype) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]


def ssim(
    pred: Tensor, target: Tensor, window: int = 11, sigma: float = 1.5, data_range: float = 1.0
) -> Tensor:
    """Mean SSIM (Wang et al. 2004, Gaussian window ``window`` px, ``sigma`` px).

    ``pred``, ``target``: ``(N, 1, H, W)``. Only the "valid" part (no padding) is averaged, as in
    scikit-image's ``structural_similarity`` with ``gaussian_weights=True``. ``data_range`` L sets
    the stabilising constants ``(0.01 L)^2`` and ``(0.03 L)^2``: below a local standard deviation
    of about 0.03 L the structure term stops seeing texture, so a smaller L weighs faint texture.
    """
    w = _gaussian_window(window, sigma, pred.dtype).to(pred.device)
    mu_x = F.conv2d(pred, w)
    mu_y = F.conv2d(target, w)
    xx = F.conv2d(pred * pred, w) - mu_x**2
    yy = F.conv2d(target * target, w) - mu_y**2
    xy = F.conv2d(pred * target, w) - mu_x * mu_y
    c1, c2 = _SSIM_C1 * data_range**2, _SSIM_C2 * data_range**2
    num = (2 * mu_x * mu_y + c1) * (2 * xy + c2)
    den = (mu_x**2 + mu_y**2 + c1) * (xx + yy + c2)
    return (num / den).mean()


def temporal_consistency(pred: Tensor, target: Tensor) -> Tensor:
    """L1 between frame-to-frame changes of prediction and target, ``(T, N, 1, H, W)`` each.

    The targets are exact (simulated), so the change of the target between consecutive windows
    replaces the optical-flow warping of the published temporal losses: flicker that the scene
    does not have is penalised. Zero when ``T < 2``.
    """
    if pred.shape[0] < 2:
        return pred.new_zeros(())
    return (torch.diff(pred, dim=0) - torch.diff(target, dim=0)).abs().mean()


def affine_align(pred: Tensor, target: Tensor, eps: float = 1e-4) -> Tensor:
    """``a * pred + b`` with the per-frame ``(a, b)`` minimising ``||a pred + b - target||^2``.

    ``pred``, ``target``: ``(N, 1, H, W)``. ``eps`` (a standard deviation) damps the gain of a
    nearly flat predicted frame towards 0, so the alignment never divides by zero.
    Differentiable in ``pred``.
    """
    dims = (1, 2, 3)
    mp = pred.mean(dims, keepdim=True)
    mt = target.mean(dims, keepdim=True)
    dp = pred - mp
    var = dp.square().mean(dims, keepdim=True)
    # gain >= 0: an inverted frame is not the target up to a gain (the anchor term fixes the sign)
    a = (dp * (target - mt)).mean(dims, keepdim=True).clamp_min(0) / (var + eps**2)
    return a * dp + mt


def gradient_matching(pred: Tensor, target: Tensor, scales: int = 4) -> Tensor:
    """Mean over ``scales`` of the L1 between the finite differences of ``pred`` and ``target``.

    ``pred``, ``target``: ``(N, 1, H, W)``; scale ``k`` compares them after ``2**k`` x ``2**k``
    average pooling. Zero for a prediction equal to the target up to an offset.
    """
    total = pred.new_zeros(())
    used = 0
    for k in range(scales):
        if k:
            pred = F.avg_pool2d(pred, 2)
            target = F.avg_pool2d(target, 2)
        if min(pred.shape[-2:]) < 2:
            break
        diff = pred - target
        gx = (diff[..., :, 1:] - diff[..., :, :-1]).abs().mean()
        gy = (diff[..., 1:, :] - diff[..., :-1, :]).abs().mean()
        total = total + gx + gy
        used += 1
    return total / max(used, 1)


def lowfreq_l1(pred: Tensor, target: Tensor, blocks: tuple[int, ...] = (4, 8)) -> Tensor:
    """Mean over ``blocks`` of the L1 between ``b x b`` block means of ``pred`` and ``target``.

    ``pred``, ``target``: ``(N, 1, H, W)``. Blind to errors that average out within a block (noise,
    texture detail); a block size that does not fit the frame is skipped.
    """
    total = pred.new_zeros(())
    used = 0
    for b in blocks:
        if min(pred.shape[-2:]) < b:
            continue
        total = total + (F.avg_pool2d(pred, b) - F.avg_pool2d(target, b)).abs().mean()
        used += 1
    return total / max(used, 1)


@dataclass
class LossWeights:
    """Weights of the loss terms (config keys ``train.loss_*``)."""

    l1: float = 1.0
    """Weight of the mean absolute error."""
    ssim: float = 1.0
    """Weight of ``1 - SSIM``."""
    temporal: float = 0.2
    """Weight of the temporal-consistency term."""
    affine_invariant: bool = False
    """L1 and SSIM after each frame's least-squares gain and offset onto its target."""
    anchor: float = 0.0
    """Weight of a plain L1 on the raw output (keeps it in [0, 1] when ``affine_invariant``)."""
    gradient: float = 0.0
    """Weight of the multi-scale gradient-matching term (:func:`gradient_matching`)."""
    lowfreq: float = 0.0
    """Weight of the block-mean L1 (:func:`lowfreq_l1`)."""
    ssim_range: float = 1.0
    """Data range of the SSIM term's constants (:func:`ssim`); 1 is the standard SSIM."""


def reconstruction_loss(
    pred: Tensor, target: Tensor, weights: LossWeights
) -> tuple[Tensor, dict[str, float]]:
    """Weighted sum of the terms over a chunk of windows ``(T, N, 1, H, W)``; also the terms as floats."""
    t, n = pred.shape[:2]
    flat_p = pred.reshape(t * n, *pred.shape[2:])
    flat_t = target.reshape(t * n, *target.shape[2:])
    raw_l1 = (flat_p - flat_t).abs().mean()
    if weights.affine_invariant:
        aligned = affine_align(flat_p, flat_t)
        l1 = (aligned - flat_t).abs().mean()
        s = ssim(aligned, flat_t, data_range=weights.ssim_range)
        tc = temporal_consistency(aligned.reshape(pred.shape), target)
    else:
        aligned = flat_p
        l1, s = raw_l1, ssim(flat_p, flat_t, data_range=weights.ssim_range)
        tc = temporal_consistency(pred, target)
    total = weights.l1 * l1 + weights.ssim * (1 - s) + weights.temporal * tc
    grad = gradient_matching(aligned, flat_t) if weights.gradient else pred.new_zeros(())
    total = total + weights.gradient * grad
    low = lowfreq_l1(aligned, flat_t) if weights.lowfreq else pred.new_zeros(())
    total = total + weights.lowfreq * low
    if weights.anchor:
        total = total + weights.anchor * raw_l1
    return total, {
        "l1": float(l1.detach()),
        "ssim": float(s.detach()),
        "temporal": float(tc.detach()),
        "raw_l1": float(raw_l1.detach()),
        "gradient": float(grad.detach()),
        "lowfreq": float(low.detach()),
        "loss": float(total.detach()),
    }
