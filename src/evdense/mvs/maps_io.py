"""COLMAP dense-workspace array files (depth, normal, cost maps) and PNG previews.

COLMAP's ``mvs::Mat<float>`` format: an ASCII header ``"{width}&{height}&{channels}&"`` followed by
``width * height * channels`` little-endian float32 values, channel-major: all of channel 0 in
row-major order, then channel 1, ... (``data[c * W * H + row * W + col]``). Depth maps have one
channel (z-depth in the camera frame, metres or model units; 0 = invalid), normal maps three
(unit normal in the camera frame, pointing towards the camera).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evdense.formats.files import atomic_path, write_atomic
from evdense.log import get_logger

log = get_logger("mvs")


def write_colmap_array(path: str | Path, array: np.ndarray) -> None:
    """Write ``(H, W)`` or ``(H, W, C)`` float data as a COLMAP ``.bin`` array, atomically.

    The file is written under a temporary name in the same folder and renamed, so a reader
    never sees a half-written map.
    """
    path = Path(path)
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or min(a.shape) == 0:
        raise ValueError(f"{path}: expected an (H, W) or (H, W, C) array, got shape {a.shape}")
    h, w, c = a.shape
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(f"{w}&{h}&{c}&".encode("ascii"))
        f.write(np.ascontiguousarray(a.transpose(2, 0, 1)).astype("<f4").tobytes())


def read_colmap_array(path: str | Path) -> np.ndarray:
    """Read a COLMAP ``.bin`` array; returns ``(H, W)`` for one channel, else ``(H, W, C)`` float32.

    Raises ``ValueError`` naming the file when the header or the data size is wrong.
    """
    path = Path(path)
    raw = path.read_bytes()
    fields: list[int] = []
    pos = 0
    for _ in range(3):
        end = raw.find(b"&", pos)
        if end < 0 or end - pos > 12:
            raise ValueError(
                f"{path}: not a COLMAP array (header 'width&height&channels&' missing)"
            )
        try:
            fields.append(int(raw[pos:end].decode("ascii")))
        except (UnicodeDecodeError, ValueError) as e:
            raise ValueError(
                f"{path}: not a COLMAP array (bad header field {raw[pos:end]!r})"
            ) from e
        pos = end + 1
    w, h, c = fields
    if w <= 0 or h <= 0 or c <= 0:
        raise ValueError(f"{path}: bad array size {w}x{h}x{c}")
    n = w * h * c
    if len(raw) - pos != 4 * n:
        raise ValueError(
            f"{path}: header says {w}x{h}x{c} floats, file holds {(len(raw) - pos) / 4:g}"
        )
    data = np.frombuffer(raw, dtype="<f4", count=n, offset=pos).astype(np.float32)
    a = data.reshape(c, h, w).transpose(1, 2, 0)
    return a[:, :, 0].copy() if c == 1 else np.ascontiguousarray(a)


def _write_png_atomic(path: Path, image: np.ndarray) -> None:
    import imageio.v3 as iio

    write_atomic(path, lambda tmp: iio.imwrite(tmp, image), keep_suffix=True)


def depth_preview(depth: np.ndarray, percentiles: tuple[float, float] = (2.0, 98.0)) -> np.ndarray:
    """A colour-mapped ``(H, W, 3)`` uint8 image of an ``(H, W)`` depth map (invalid = black).

    Near is bright (inverse depth through matplotlib's turbo map), scaled between percentiles of
    the valid depths.
    """
    from matplotlib import colormaps

    valid = depth > 0
    out = np.zeros((*depth.shape, 3), np.uint8)
    if not valid.any():
        return out
    inv = np.zeros_like(depth, dtype=np.float64)
    inv[valid] = 1.0 / depth[valid]
    lo, hi = np.percentile(inv[valid], percentiles)
    t = np.clip((inv - lo) / max(hi - lo, 1e-12), 0, 1)
    rgb = (colormaps["turbo"](t)[..., :3] * 255).astype(np.uint8)
    out[valid] = rgb[valid]
    return out


def normal_preview(normal: np.ndarray) -> np.ndarray:
    """An ``(H, W, 3)`` uint8 image of an ``(H, W, 3)`` camera-frame normal map: RGB = (n + 1) / 2,
    with the normal flipped to +z so that a fronto-parallel surface is blue-ish; zero normals black."""
    n = np.asarray(normal, dtype=np.float64)
    valid = np.linalg.norm(n, axis=-1) > 0.5
    rgb = np.clip((-n + 1) * 127.5, 0, 255).astype(np.uint8)
    rgb[~valid] = 0
    return rgb


def write_previews(stem: str | Path, depth: np.ndarray, normal: np.ndarray | None = None) -> None:
    """Write ``{stem}.depth.png`` (and ``{stem}.normal.png`` when a normal map is given)."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    _write_png_atomic(stem.with_name(stem.name + ".depth.png"), depth_preview(depth))
    if normal is not None:
        _write_png_atomic(stem.with_name(stem.name + ".normal.png"), normal_preview(normal))
