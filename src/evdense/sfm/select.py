"""Which frames of a folder go to SfM (``sfm.select``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evdense.formats.frames import Frame
from evdense.sfm.config import SfmConfig


def _load_small_grey(path: Path, factor: int = 4) -> np.ndarray:
    import imageio.v3 as iio

    img = np.asarray(iio.imread(path), dtype=np.float32)
    if img.ndim == 3:
        img = img[..., :3].mean(axis=-1)
    img /= 255.0 if img.max() > 1.5 else 1.0
    h, w = (img.shape[0] // factor) * factor, (img.shape[1] // factor) * factor
    if h == 0 or w == 0:
        return img
    return img[:h, :w].reshape(h // factor, factor, w // factor, factor).mean(axis=(1, 3))


def select_frames(frames: list[Frame], frames_dir: Path, cfg: SfmConfig) -> list[Frame]:
    """Frames given to SfM, in time order, following ``cfg.select`` (the first and last are kept)."""
    n = len(frames)
    if cfg.select == "all" or n <= 2:
        return list(frames)
    if cfg.select == "every_k":
        idx = list(range(0, n, cfg.select_every_k))
    elif cfg.select == "count":
        if cfg.select_count >= n:
            return list(frames)
        idx = np.unique(np.round(np.linspace(0, n - 1, cfg.select_count)).astype(int)).tolist()
    else:  # change
        idx = [0]
        ref = _load_small_grey(frames_dir / frames[0].name)
        for i in range(1, n):
            img = _load_small_grey(frames_dir / frames[i].name)
            if img.shape != ref.shape:
                raise ValueError(
                    f"{frames_dir / frames[i].name}: size {img.shape} differs from the first frame's"
                )
            if float(np.abs(img - ref).mean()) > cfg.select_min_change:
                idx.append(i)
                ref = img
    if idx[-1] != n - 1:
        idx.append(n - 1)
    return [frames[i] for i in idx]
