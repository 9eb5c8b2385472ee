"""Pre- and post-processing around reconstruction: input normalisation, tone mapping.

- :func:`standardize_nonzero`: the published input normalisation of E2VID and FireNet (non-zero
  voxels to mean 0, std 1); the "+" models take raw voxels.
- :func:`unsharp_mask`, :class:`RobustRescaler` ("auto HDR": robust min/max from percentiles,
  medians over recent frames so that the brightness does not flicker).

The frames folder the reconstruction writes is defined in :mod:`evdense.formats.frames`.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import torch
from scipy.ndimage import gaussian_filter


def standardize_nonzero(voxels: torch.Tensor) -> torch.Tensor:
    """Scale the non-zero entries of a voxel grid to mean 0 and standard deviation 1, in place.

    The normalisation E2VID and FireNet were trained with (rpg_e2vid's ``EventPreprocessor``):
    statistics over the non-zero entries of the whole tensor ``(..., B, H, W)``, unbiased
    standard deviation; zeros stay zero. A grid with fewer than two non-zero entries, or with
    all of them equal, is left unchanged except for centring.

    Returns ``voxels`` (modified).
    """
    mask = voxels != 0
    n = int(torch.count_nonzero(mask))
    if n == 0:
        return voxels
    # Sums instead of boolean indexing: two reductions and three in-place passes, about twice as
    # fast; zeros add nothing to either sum. Moments in float64.
    flat = voxels.reshape(-1)
    mean = float(flat.sum(dtype=torch.float64)) / n
    sq = float(torch.dot(flat, flat)) if voxels.is_contiguous() else float((flat * flat).sum())
    var = (sq - n * mean * mean) / (n - 1) if n > 1 else 0.0
    voxels.sub_(mean).mul_(mask)
    if var > 1e-12 * sq / n:  # not all equal (rounding leaves a tiny var otherwise)
        voxels.div_(var**0.5)
    return voxels


def unsharp_mask(image: np.ndarray, sigma: float = 1.0, amount: float = 0.3) -> np.ndarray:
    """Sharpen ``image`` (H, W) in [0, 1]: ``(1 + amount) * I - amount * gaussian(I, sigma)``.

    ``sigma`` in pixels. The result is clipped to [0, 1].
    """
    if amount <= 0:
        return image
    blurred = gaussian_filter(image, sigma=sigma, mode="nearest")
    return np.clip((1.0 + amount) * image - amount * blurred, 0.0, 1.0)


class RobustRescaler:
    """Map images to [0, 1] with a robust min/max smoothed over the last frames ("auto HDR").

    For each image the ``min_percentile`` and ``max_percentile`` of its pixels (ignoring a
    ``border`` of pixels, where networks produce outliers) are computed; the medians of these
    bounds over the last ``window`` images map to 0 and 1, and the result is clipped.
    Call :meth:`reset` at a cut in the stream.
    """

    def __init__(
        self,
        min_percentile: float = 1.0,
        max_percentile: float = 99.0,
        window: int = 10,
        border: int = 4,
    ) -> None:
        if not 0 <= min_percentile < max_percentile <= 100:
            raise ValueError(
                f"percentiles must satisfy 0 <= min < max <= 100, got {min_percentile}, {max_percentile}"
            )
        if window < 1:
            raise ValueError(f"window must be >= 1 frame, got {window}")
        self.min_percentile = min_percentile
        self.max_percentile = max_percentile
        self.border = max(0, int(border))
        self._bounds: deque[tuple[float, float]] = deque(maxlen=int(window))

    def reset(self) -> None:
        self._bounds.clear()

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Rescaled float32 copy of ``image`` (H, W), values in [0, 1]."""
        b = self.border
        core = image[b:-b, b:-b] if b and min(image.shape) > 2 * b else image
        lo, hi = np.percentile(core, (self.min_percentile, self.max_percentile))
        self._bounds.append((float(lo), float(hi)))
        lo = float(np.median([x[0] for x in self._bounds]))
        hi = float(np.median([x[1] for x in self._bounds]))
        scale = 1.0 / (hi - lo) if hi > lo else 0.0
        out = (image.astype(np.float32) - np.float32(lo)) * np.float32(scale)
        return np.clip(out, 0.0, 1.0, out=out)
