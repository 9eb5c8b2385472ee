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
weights 2 and 8 did not change that (the ablation table in docs/training.md).
``LossWeights.ssim_range`` gives the SSIM term the constants of a smaller data range, so that it
weighs texture too faint for the standard SSIM (on the real clips a trade, not a gain: same table).
``LossWeights.perceptual`` adds a feature loss without pretrained weights (:func:`random_feature_loss`):
LPIPS's distance between unit-normalised activations, taken on a fixed, randomly initialised
VGG-shaped network at four scales instead of an ImageNet VGG, which we may not download ("Generic
Perceptual Loss", Liu et al., CVPR 2021, found random networks to serve as perceptual losses;
E2VID and FireNet trained with LPIPS). It compares the pattern of local structure at receptive
fields from 5 to about 70 px, not its gain; fine-tunes at weights 1 and 4 lowered every figure a
little (same table).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

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


class RandomFeatures(torch.nn.Module):
    """A frozen VGG-shaped network with random weights: four stages of two 3 x 3 convolutions.

    Stage ``k`` has ``channels[k]`` channels; every stage after the first starts by halving the
    resolution (2 x 2 max pooling). Weights are drawn once from ``seed`` with He (Kaiming) scaling
    and zero biases, so activations keep the input's scale from stage to stage and every run draws
    the same network: nothing is downloaded or shipped. :meth:`forward` returns each stage's
    output.
    """

    def __init__(self, seed: int = 0, channels: tuple[int, ...] = (16, 32, 64, 64)) -> None:
        super().__init__()
        gen = torch.Generator().manual_seed(seed)
        self.stages = torch.nn.ModuleList()
        c_in = 1
        for c in channels:
            convs = [torch.nn.Conv2d(c_in, c, 3, padding=1), torch.nn.Conv2d(c, c, 3, padding=1)]
            for conv in convs:
                torch.nn.init.kaiming_normal_(conv.weight, nonlinearity="relu", generator=gen)
                torch.nn.init.zeros_(conv.bias)
            self.stages.append(
                torch.nn.Sequential(convs[0], torch.nn.ReLU(), convs[1], torch.nn.ReLU())
            )
            c_in = c
        self.requires_grad_(False)
        self.eval()

    def forward(self, x: Tensor) -> list[Tensor]:
        feats = []
        h = x - 0.5  # targets lie in [0, 1]: centre them so the ReLUs see both signs
        for i, stage in enumerate(self.stages):
            if i:
                h = F.max_pool2d(h, 2)
            h = stage(h)
            feats.append(h)
        return feats


@lru_cache(maxsize=4)
def _random_features(device: str, dtype: torch.dtype) -> RandomFeatures:
    return RandomFeatures().to(device=device, dtype=dtype)


def random_feature_loss(pred: Tensor, target: Tensor, eps: float = 0.05) -> Tensor:
    """Perceptual distance: mean over the stages of :class:`RandomFeatures`, as LPIPS computes it.

    As LPIPS (Zhang et al. 2018) without its learned channel weights: at each pixel of each stage
    the activation vector is divided by its length (softened by ``eps``, which keeps the gradient
    bounded where a stage barely responds) and the squared differences are summed over channels
    and averaged over pixels. It compares the pattern of local structure, not its gain: a frame
    scaled about mid-grey (0.5) scores 0, a blurred or flattened one high. ``pred``, ``target``:
    ``(N, 1, H, W)``; gradients flow to ``pred`` only. A stage whose resolution would fall below
    2 px is skipped.
    """
    net = _random_features(str(pred.device), pred.dtype)
    total = pred.new_zeros(())
    used = 0
    with torch.no_grad():
        feats_t = net(target)
    for fp, ft in zip(net(pred), feats_t, strict=True):
        if min(fp.shape[-2:]) < 2:
            break
        up = fp * torch.rsqrt(fp.square().sum(1, keepdim=True) + eps**2)
        ut = ft * torch.rsqrt(ft.square().sum(1, keepdim=True) + eps**2)
        total = total + (up - ut).square().sum(1).mean()
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
    perceptual: float = 0.0
    """Weight of the random-feature perceptual distance (:func:`random_feature_loss`)."""


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
    feat = random_feature_loss(aligned, flat_t) if weights.perceptual else pred.new_zeros(())
    total = total + weights.perceptual * feat
    if weights.anchor:
        total = total + weights.anchor * raw_l1
    return total, {
        "l1": float(l1.detach()),
        "ssim": float(s.detach()),
        "temporal": float(tc.detach()),
        "raw_l1": float(raw_l1.detach()),
        "gradient": float(grad.detach()),
        "lowfreq": float(low.detach()),
        "perceptual": float(feat.detach()),
        "loss": float(total.detach()),
    }
