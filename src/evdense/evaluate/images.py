"""Image metrics of reconstructed or conventional frames against GT intensity."""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity


def normalize_intensity(
    img: np.ndarray, low_pct: float = 1.0, high_pct: float = 99.0
) -> np.ndarray:
    """Robustly rescale an image to [0, 1] by its percentiles (``(H, W)`` float64)."""
    img = np.asarray(img, dtype=np.float64)
    lo, hi = np.percentile(img, [low_pct, high_pct])
    return np.clip((img - lo) / max(hi - lo, 1e-12), 0.0, 1.0)


def image_metrics(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """MSE, PSNR (dB) and SSIM of ``pred`` against ``gt``, both ``(H, W)`` in [0, 1]."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ValueError(f"image shapes differ: {pred.shape} vs {gt.shape}")
    mse = float(np.mean((pred - gt) ** 2))
    psnr = float(10 * np.log10(1.0 / mse)) if mse > 0 else float("inf")
    ssim = float(structural_similarity(pred, gt, data_range=1.0))
    return {"mse": mse, "psnr": psnr, "ssim": ssim}
