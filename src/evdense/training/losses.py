"""Losses for training a reconstruction network: L1, SSIM and a temporal-consistency term.

All take predictions and targets ``(N, 1, H, W)`` (or a stack ``(T, N, 1, H, W)`` for the
temporal term) in target units ([0, 1]) and return a scalar tensor.
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


def ssim(pred: Tensor, target: Tensor, window: int = 11, sigma: float = 1.5) -> Tensor:
    """Mean SSIM (Wang et al. 2004, data range 1, Gaussian window ``window`` px, ``sigma`` px).

    ``pred``, ``target``: ``(N, 1, H, W)``. Only the "valid" part (no padding) is averaged, as in
    scikit-image's ``structural_similarity`` with ``gaussian_weights=True``.
    """
    w = _gaussian_window(window, sigma, pred.dtype).to(pred.device)
    mu_x = F.conv2d(pred, w)
    mu_y = F.conv2d(target, w)
    xx = F.conv2d(pred * pred, w) - mu_x**2
    yy = F.conv2d(target * target, w) - mu_y**2
    xy = F.conv2d(pred * target, w) - mu_x * mu_y
    num = (2 * mu_x * mu_y + _SSIM_C1) * (2 * xy + _SSIM_C2)
    den = (mu_x**2 + mu_y**2 + _SSIM_C1) * (xx + yy + _SSIM_C2)
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


@dataclass
class LossWeights:
    """Weights of the loss terms (config keys ``train.loss_*``)."""

    l1: float = 1.0
    """Weight of the mean absolute error."""
    ssim: float = 1.0
    """Weight of ``1 - SSIM``."""
    temporal: float = 0.2
    """Weight of the temporal-consistency term."""


def reconstruction_loss(
    pred: Tensor, target: Tensor, weights: LossWeights
) -> tuple[Tensor, dict[str, float]]:
    """Weighted sum of the terms over a chunk of windows ``(T, N, 1, H, W)``; also the terms as floats."""
    t, n = pred.shape[:2]
    flat_p = pred.reshape(t * n, *pred.shape[2:])
    flat_t = target.reshape(t * n, *target.shape[2:])
    l1 = (flat_p - flat_t).abs().mean()
    s = ssim(flat_p, flat_t)
    tc = temporal_consistency(pred, target)
    total = weights.l1 * l1 + weights.ssim * (1 - s) + weights.temporal * tc
    return total, {
        "l1": float(l1.detach()),
        "ssim": float(s.detach()),
        "temporal": float(tc.detach()),
        "loss": float(total.detach()),
    }
