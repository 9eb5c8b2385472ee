"""Image metrics of reconstructed or conventional frames against GT intensity (rendered at the
frames' times), against a recording's own APS frames, and of a textured mesh's renders from
held-out GT cameras."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from skimage.metrics import structural_similarity

from evdense.evaluate.align import apply_h, apply_sim3
from evdense.evaluate.config import EvalConfig
from evdense.formats.frames import frame_paths_and_times
from evdense.poses import read_tum


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


def evaluate_images(frames_dir: Path, gt_dir: Path, conf: EvalConfig) -> dict[str, Any]:
    """MSE, PSNR and SSIM of a frames folder against GT intensity rendered at the frames' times."""
    import imageio.v3 as iio

    from evdense.sim.groundtruth import render_gt_intensity

    paths, ts = frame_paths_and_times(frames_dir)
    if not paths:
        return {"num_frames": 0}
    pick = np.unique(
        np.linspace(0, len(paths) - 1, min(conf.max_image_frames, len(paths))).round().astype(int)
    )
    gt = render_gt_intensity(gt_dir, ts[pick])
    per = []
    for k, i in enumerate(pick):
        img = iio.imread(paths[i]).astype(np.float64)
        if img.ndim == 3:
            img = img[..., :3].mean(-1)
        per.append(compare_to_gt(img, gt[k], conf.image_mode))
    out = {k: float(np.mean([m[k] for m in per])) for k in ("mse", "psnr", "ssim")}
    out["num_frames"] = len(per)
    return out


def evaluate_against_reference(
    frames_dir: Path, reference_dir: Path, conf: EvalConfig, max_shift: int = 10
) -> dict[str, Any]:
    """MSE and SSIM of frames against the recording's nearest APS frame (EVREAL-style: each image
    rescaled by its 1st-99th percentiles, best integer shift within ``max_shift`` px; see
    :func:`evdense.evaluate.real_frames.shifted_metrics`). Reference frames more than half the
    median frame interval from every frame are not used."""
    import imageio.v3 as iio

    from evdense.evaluate.real_frames import shifted_metrics

    if frames_dir.resolve() == reference_dir.resolve():
        return {"reference": "aps_nearest", "num_frames": 0, "note": "the source is the reference"}
    paths, ts = frame_paths_and_times(frames_dir)
    ref_paths, ref_ts = frame_paths_and_times(reference_dir)
    out: dict[str, Any] = {"reference": "aps_nearest", "num_frames": 0}
    if not paths or not ref_paths:
        return out
    gap = float(np.median(np.diff(ts))) if len(ts) > 1 else np.inf
    pairs = []
    for j, tr in enumerate(ref_ts):
        i = int(np.argmin(np.abs(ts - tr)))
        if abs(ts[i] - tr) <= gap / 2:
            pairs.append((i, j))
    if len(pairs) > conf.max_image_frames:
        keep = np.linspace(0, len(pairs) - 1, conf.max_image_frames).round().astype(int)
        pairs = [pairs[k] for k in np.unique(keep)]
    per = []
    for i, j in pairs:
        img = iio.imread(paths[i]).astype(np.float64)
        ref = iio.imread(ref_paths[j]).astype(np.float64)
        img = img[..., :3].mean(-1) if img.ndim == 3 else img
        ref = ref[..., :3].mean(-1) if ref.ndim == 3 else ref
        if img.shape != ref.shape:
            continue
        per.append(shifted_metrics(img, ref, max_shift))
    if per:
        out.update({k: float(np.mean([m[k] for m in per])) for k in ("mse", "ssim")})
    out["num_frames"] = len(per)
    return out


def evaluate_textured(
    obj_path: Path,
    sim3: tuple[float, np.ndarray, np.ndarray],
    H: np.ndarray,
    gt_dir: Path,
    conf: EvalConfig,
) -> dict[str, Any]:
    """PSNR and SSIM of the textured mesh rendered from held-out GT cameras against GT images.

    The mesh is moved into the GT frame (Sim(3) then ICP); GT cameras sit midway between the GT
    frame times. Scores are over the pixels the mesh covers, after matching the render's grey
    levels to the GT log image (as for frames); ``coverage`` is that pixel fraction.
    """
    from skimage.exposure import match_histograms

    from evdense.camera import load_camera
    from evdense.evaluate.images import log_reference
    from evdense.evaluate.rendering import render_textured
    from evdense.sim.groundtruth import render_gt_intensity
    from evdense.texture import read_textured_mesh

    tm = read_textured_mesh(obj_path)
    s, R, t = sim3
    v = apply_sim3(s, R, t, tm.vertices)
    tm.vertices = apply_h(H, v)
    cam = load_camera(gt_dir / "intrinsics.yaml")
    frame_t = frame_paths_and_times(gt_dir / "frames")[1]
    mids = (frame_t[:-1] + frame_t[1:]) / 2
    if len(mids) == 0:
        return {"num_views": 0}
    mids = mids[
        np.unique(
            np.linspace(0, len(mids) - 1, min(conf.heldout_views, len(mids))).round().astype(int)
        )
    ]
    t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
    from evdense.poses import interpolate_poses

    _, poses = interpolate_poses(mids, t_gt, T_gt)
    gt = render_gt_intensity(gt_dir, mids)
    psnr, ssim, cover = [], [], []
    for k in range(len(mids)):
        img, mask = render_textured(tm, cam, poses[k])
        cover.append(float(mask.mean()))
        if mask.sum() < 100:
            continue
        grey = img[..., :3].mean(-1) if img.ndim == 3 else img
        ref = log_reference(gt[k])
        matched = np.clip(match_histograms(grey[mask].astype(np.float64), ref[mask]), 0, 1)
        mse = float(np.mean((matched - ref[mask]) ** 2))
        psnr.append(10 * np.log10(1 / mse) if mse > 0 else float("inf"))
        full = ref.copy()
        full[mask] = matched
        from skimage.metrics import structural_similarity

        ssim.append(float(structural_similarity(full, ref, data_range=1.0)))
    return {
        "num_views": len(mids),
        "psnr": float(np.mean(psnr)) if psnr else 0.0,
        "ssim": float(np.mean(ssim)) if ssim else 0.0,
        "coverage": float(np.mean(cover)),
    }
