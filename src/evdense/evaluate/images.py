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


def log_reference(radiance: np.ndarray, low_pct: float = 0.1, high_pct: float = 99.9) -> np.ndarray:
    """GT radiance ``(H, W)`` as a display image in [0, 1]: log, rescaled between percentiles.

    The log keeps dark regions of HDR scenes visible, as in the GT frames PNGs.
    """
    return normalize_intensity(
        np.log(np.maximum(np.asarray(radiance, np.float64), 1e-6)), low_pct, high_pct
    )


def compare_to_gt(
    pred: np.ndarray, gt_radiance: np.ndarray, mode: str = "histogram"
) -> dict[str, float]:
    """MSE, PSNR and SSIM of a frame (any tone curve) against GT radiance.

    Frames of different sources have different, arbitrary tone curves (a network's output, a linear
    8-bit camera, a log-mapped GT frame), so both are brought to a common footing first:

    - ``histogram``: the GT is log-mapped to [0, 1] (:func:`log_reference`) and the frame's grey
      levels are remapped to the GT's histogram (a monotonic map: structure is compared, tone curve
      is not; saturated or missing regions stay wrong);
    - ``percentile``: both are rescaled by their own 1st-99th percentiles (GT in linear radiance).
    """
    if mode == "histogram":
        from skimage.exposure import match_histograms

        ref = log_reference(gt_radiance)
        return image_metrics(
            np.clip(match_histograms(np.asarray(pred, np.float64), ref), 0, 1), ref
        )
    if mode == "percentile":
        return image_metrics(normalize_intensity(pred), normalize_intensity(gt_radiance))
    raise ValueError(f"unknown image comparison mode {mode!r} (histogram, percentile)")


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
