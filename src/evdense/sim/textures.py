"""Grayscale reflectance textures (procedural and from image files) and their mip-map pyramids.

A texture is a ``(h, w)`` float32 array of linear reflectance in ``(0, 1]`` whose sides are powers of
two, tiling seamlessly for the procedural kinds. Texture specs are small dicts (YAML-friendly)::

    {type: dead_leaves, size: 512, rmin: 3, rmax: 160, alpha: 3.0, low: 0.05, high: 0.9}
    {type: noise, size: 512, beta: 2.6, fmin: 2, low: 0.08, high: 0.85, sharpness: 1.3}
    {type: checker, size: 256, squares: 8, low: 0.1, high: 0.8}
    {type: image, path: skimage:brick | /path/to/file.png, low: 0.05, high: 0.9}
    {type: constant, value: 0.5}

Every kind but ``constant`` also takes ``repeat`` (tile the pattern ``repeat`` x ``repeat`` times in
one texture, a power of two) and ``variation`` (``0 <= a < 1``: multiply by a smooth noise between
``1 - a`` and ``1 + a``), so that a repeated pattern such as bricks never repeats exactly.
A bare string is shorthand: ``"skimage:brick"`` or a file path means ``{type: image, path: ...}``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

SKIMAGE_PREFIX = "skimage:"
TEXTURE_TYPES = ("dead_leaves", "noise", "checker", "image", "constant")
_DEFAULTS: dict[str, dict] = {
    "dead_leaves": {
        "size": 512,
        "rmin": 3.0,
        "rmax": 160.0,
        "alpha": 3.0,
        "low": 0.05,
        "high": 0.9,
    },
    "noise": {"size": 512, "beta": 2.6, "fmin": 2.0, "low": 0.08, "high": 0.85, "sharpness": 1.3},
    "checker": {"size": 256, "squares": 8, "low": 0.1, "high": 0.8},
    "image": {"low": 0.05, "high": 0.9, "max_size": 1024},
    "constant": {"value": 0.5, "size": 1},
}
# options of every non-constant type: tile the pattern `repeat` x `repeat` times inside one texture
# and multiply it by a smooth noise of relative amplitude `variation`, so that a repeated pattern
# (bricks) does not repeat exactly (which would confuse feature matching)
_COMMON = {"repeat": 1, "variation": 0.0}
MAX_TEXTURE_SIDE = 4096


def normalize_texture_spec(spec: str | dict, key: str, base_dir: Path | None = None) -> dict:
    """Validate a texture spec and fill its defaults; returns a new dict (image paths made absolute).

    ``key`` names the spec in error messages (e.g. ``materials.wall.texture``). Raises ``ValueError``
    naming ``key`` for an unknown type, an unknown option or a missing image file.
    """
    if isinstance(spec, str):
        spec = {"type": "image", "path": spec}
    if not isinstance(spec, dict):
        raise ValueError(f"{key}: expected a texture spec (dict or image path), got {spec!r}")
    kind = spec.get("type")
    if kind not in TEXTURE_TYPES:
        raise ValueError(
            f"{key}.type: unknown texture type {kind!r} (known: {', '.join(TEXTURE_TYPES)})"
        )
    common = _COMMON if kind != "constant" else {}
    out = {"type": kind, **_DEFAULTS[kind], **common}
    allowed = set(out) | {"seed"} | ({"path"} if kind == "image" else set())
    for k, v in spec.items():
        if k not in allowed:
            raise ValueError(
                f"{key}.{k}: unknown option for a {kind} texture (known: {sorted(allowed)})"
            )
        out[k] = v
    if kind == "image":
        path = out.get("path")
        if not isinstance(path, str) or not path:
            raise ValueError(
                f"{key}.path: an image texture needs a path (file or 'skimage:<name>')"
            )
        if path.startswith(SKIMAGE_PREFIX):
            import skimage.data

            name = path[len(SKIMAGE_PREFIX) :]
            if not callable(getattr(skimage.data, name, None)):
                raise ValueError(f"{key}.path: no image {name!r} in skimage.data")
        else:
            p = Path(path).expanduser()
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            if not p.is_file():
                raise ValueError(f"{key}.path: texture file not found: {p}")
            out["path"] = str(p.resolve())
    for sk in ("size", "max_size"):
        if sk in out and kind != "constant":
            size = out[sk]
            if isinstance(size, bool) or not isinstance(size, int) or size < 2 or size & (size - 1):
                raise ValueError(f"{key}.{sk}: must be a power of two >= 2, got {size!r}")
    if kind != "constant":
        rep, var = out["repeat"], out["variation"]
        if isinstance(rep, bool) or not isinstance(rep, int) or rep < 1 or rep & (rep - 1):
            raise ValueError(f"{key}.repeat: must be a power of two >= 1, got {rep!r}")
        side = int(out.get("size", out.get("max_size", 1))) * rep
        if side > MAX_TEXTURE_SIDE:
            raise ValueError(f"{key}: size x repeat = {side} texels exceeds {MAX_TEXTURE_SIDE}")
        if not (isinstance(var, int | float) and 0 <= var < 1):
            raise ValueError(f"{key}.variation: must be in [0, 1), got {var!r}")
    lo, hi = out.get("low", 0.5), out.get("high", 0.5)
    if not 0 < lo <= hi:
        raise ValueError(f"{key}: need 0 < low <= high, got low={lo}, high={hi}")
    if kind == "constant" and not out["value"] > 0:
        raise ValueError(f"{key}.value: reflectance must be > 0, got {out['value']}")
    return out


def texture_seed(seed: int, name: str) -> int:
    """A stable per-texture seed from the dataset seed and the material name."""
    return (int(seed) * 1_000_003 + zlib.crc32(name.encode())) % (2**32)


def make_texture(spec: dict, seed: int = 0) -> np.ndarray:
    """Build the ``(h, w)`` float32 reflectance array of a normalised spec (sides powers of two)."""
    return _make_texture_cached(_freeze(spec), int(spec.get("seed", seed))).copy()


def _freeze(spec: dict) -> tuple:
    return tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in spec.items()))


@lru_cache(maxsize=64)
def _make_texture_cached(frozen: tuple, seed: int) -> np.ndarray:
    spec = dict(frozen)
    rng = np.random.default_rng(seed)
    kind = spec["type"]
    if kind == "dead_leaves":
        tex = dead_leaves(int(spec["size"]), spec["rmin"], spec["rmax"], spec["alpha"], rng)
    elif kind == "noise":
        tex = spectral_noise(int(spec["size"]), spec["beta"], spec["fmin"], spec["sharpness"], rng)
    elif kind == "checker":
        tex = checker(int(spec["size"]), int(spec["squares"]))
    elif kind == "image":
        tex = load_image_texture(spec["path"], int(spec["max_size"]))
    else:
        return np.full((1, 1), spec["value"], dtype=np.float32)
    lo, hi = float(spec["low"]), float(spec["high"])
    out = lo + (hi - lo) * tex
    rep = int(spec["repeat"])
    if rep > 1:
        out = np.tile(out, (rep, rep))
    if spec["variation"] > 0:
        h, w = out.shape
        smooth = spectral_noise(max(h, w), 3.0, 1.0, 1.0, rng)[:h, :w] if h == w else None
        if smooth is None:  # non-square: a square field cropped would not tile; resample instead
            from skimage.transform import resize

            smooth = resize(
                spectral_noise(max(h, w), 3.0, 1.0, 1.0, rng), (h, w), preserve_range=True
            )
        a = float(spec["variation"])
        out = out * (1.0 - a + 2.0 * a * smooth)  # factor in (1 - a, 1 + a), mean ~1
    out = out.astype(np.float32)
    out.setflags(write=False)
    return out


def dead_leaves_labels(
    size: int, rmin: float, rmax: float, alpha: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The occlusion layout of a periodic dead-leaves image: ``(labels, values)``, where ``labels``
    ``(size, size)`` int32 is the index of the disk seen at each texel (``-1`` where none landed)
    and ``values`` the uniform grey level drawn for each disk, in painting order. Radii (pixels)
    follow ``p(r) ~ r^-alpha`` on ``[rmin, rmax]`` (scale invariant at alpha = 3); disks are
    painted front to back until the torus is covered.
    """
    labels = np.full((size, size), -1, dtype=np.int32)
    drawn: list[np.ndarray] = []
    uncovered = size * size
    ar = np.arange(-int(np.ceil(rmax)), int(np.ceil(rmax)) + 1)
    batch = 512
    covered = False
    for b in range(400):  # bounded: each batch covers a fixed expected fraction
        # inverse-CDF sampling of a truncated power law
        u = rng.random(batch)
        a1 = 1.0 - alpha
        radii = (rmin**a1 + u * (rmax**a1 - rmin**a1)) ** (1.0 / a1)
        centres = rng.integers(0, size, size=(batch, 2))
        drawn.append(rng.random(batch).astype(np.float32))
        if covered:
            # Covered, but the count missed it: a disk wider than the torus wraps onto itself and
            # its texels were counted twice. These batches would paint nothing; their numbers are
            # still drawn, so the generator ends where it always has.
            continue
        for i, (r, (cy, cx)) in enumerate(zip(radii, centres, strict=True)):
            ri = int(np.ceil(r))
            off = ar[len(ar) // 2 - ri : len(ar) // 2 + ri + 1]
            rows = (cy + off) % size
            cols = (cx + off) % size
            disk = off[:, None] ** 2 + off[None, :] ** 2 <= r * r
            block = labels[np.ix_(rows, cols)]
            paint = disk & (block < 0)
            if paint.any():
                block[paint] = b * batch + i
                labels[np.ix_(rows, cols)] = block
                uncovered -= int(paint.sum())
        if uncovered == 0:
            break
        covered = bool(labels.min() >= 0)
    return labels, np.concatenate(drawn)


def dead_leaves(
    size: int, rmin: float, rmax: float, alpha: float, rng: np.random.Generator
) -> np.ndarray:
    """A periodic dead-leaves image ``(size, size)`` in ``[0, 1]``: occluding disks of random grey
    levels (:func:`dead_leaves_labels`); texels no disk covered are mid-grey.
    """
    labels, values = dead_leaves_labels(size, rmin, rmax, alpha, rng)
    return np.where(labels >= 0, values[np.maximum(labels, 0)], np.float32(0.5)).astype(np.float32)


def spectral_noise(
    size: int, beta: float, fmin: float, sharpness: float, rng: np.random.Generator
) -> np.ndarray:
    """Periodic multi-scale noise ``(size, size)`` in ``(0, 1)``: Gaussian noise with power spectrum
    ``~ 1/f^beta`` above ``fmin`` cycles per tile, mapped through a logistic of slope ``sharpness``
    (per standard deviation), so that all scales from the tile down to one texel carry contrast.
    """
    fy = np.fft.fftfreq(size)[:, None] * size
    fx = np.fft.rfftfreq(size)[None, :] * size
    f = np.sqrt(fx * fx + fy * fy)
    amp = np.where(f >= fmin, np.maximum(f, 1e-9) ** (-beta / 2.0), 0.0)
    white = rng.standard_normal((size, size))
    field = np.fft.irfft2(np.fft.rfft2(white) * amp, s=(size, size))
    field = (field - field.mean()) / max(field.std(), 1e-12)
    return (1.0 / (1.0 + np.exp(-sharpness * field))).astype(np.float32)


def checker(size: int, squares: int) -> np.ndarray:
    """A ``(size, size)`` checkerboard of ``squares`` x ``squares`` cells with values 0 and 1
    (``squares`` even so the tile repeats seamlessly)."""
    cell = np.arange(size) * squares // size
    return ((cell[:, None] + cell[None, :]) % 2).astype(np.float32)


def load_image_texture(path: str, max_size: int = 1024) -> np.ndarray:
    """Read an image (file or ``skimage:<name>``) as linear grey ``[0, 1]``, centre-cropped and resized
    to power-of-two sides (the nearest power of two at or below each side, at most ``max_size``)."""
    from skimage.color import rgb2gray
    from skimage.transform import resize

    if path.startswith(SKIMAGE_PREFIX):
        import skimage.data

        img = getattr(skimage.data, path[len(SKIMAGE_PREFIX) :])()
    else:
        import imageio.v3 as iio

        try:
            img = iio.imread(path)
        except Exception as exc:  # imageio raises many types for unreadable files
            raise ValueError(f"{path}: cannot read texture image ({exc})") from exc
    img = np.asarray(img)
    if img.dtype == bool:
        img = img.astype(np.float32)
    elif np.issubdtype(img.dtype, np.integer):
        img = img.astype(np.float32) / np.iinfo(img.dtype).max
    img = img.astype(np.float32)
    if img.ndim == 3:
        img = rgb2gray(img[..., :3]) if img.shape[2] >= 3 else img[..., 0]
    # sRGB-encoded files to linear reflectance (a gamma of 2.2 is close enough here)
    img = np.clip(img, 0.0, 1.0) ** 2.2
    h, w = img.shape
    ph = min(max_size, 1 << max(1, int(np.floor(np.log2(h)))))
    pw = min(max_size, 1 << max(1, int(np.floor(np.log2(w)))))
    # centre-crop to the aspect ratio of the power-of-two size, so the picture is not squashed
    if pw / ph > w / h:
        ch = int(round(w * ph / pw))
        img = img[(h - ch) // 2 : (h - ch) // 2 + ch]
    else:
        cw = int(round(h * pw / ph))
        img = img[:, (w - cw) // 2 : (w - cw) // 2 + cw]
    h, w = img.shape
    if (ph, pw) != (h, w):
        img = resize(img, (ph, pw), anti_aliasing=True, preserve_range=True)
    lo, hi = float(img.min()), float(img.max())
    return ((img - lo) / max(hi - lo, 1e-6)).astype(np.float32)


def mip_pyramid(tex: np.ndarray) -> list[np.ndarray]:
    """Mip levels of a power-of-two texture: level 0 is ``tex``, each next level the 2x2 box mean
    (wrapping sides of one texel stay one texel), down to 1x1."""
    levels = [np.ascontiguousarray(tex, dtype=np.float32)]
    while levels[-1].shape != (1, 1):
        t = levels[-1]
        h, w = t.shape
        if h > 1:
            t = 0.5 * (t[0::2] + t[1::2])
        if w > 1:
            t = 0.5 * (t[:, 0::2] + t[:, 1::2])
        levels.append(np.ascontiguousarray(t, dtype=np.float32))
    return levels


@dataclass
class TextureAtlas:
    """All mip levels of all textures packed in one flat array, for vectorised trilinear lookup.

    ``offset[k, L]``, ``width[k, L]``, ``height[k, L]`` locate level ``L`` of texture ``k`` in
    ``texels`` (levels past a texture's last are repeats of its 1x1 level); ``scale_u/scale_v[k, L]``
    map level-0 texel coordinates to level-``L`` texel coordinates; ``num_levels[k]`` counts levels.
    """

    texels: np.ndarray
    offset: np.ndarray
    width: np.ndarray
    height: np.ndarray
    scale_u: np.ndarray
    scale_v: np.ndarray
    num_levels: np.ndarray

    @classmethod
    def build(cls, textures: list[np.ndarray]) -> TextureAtlas:
        pyramids = [mip_pyramid(t) for t in textures]
        # one spare column so that trilinear lookups may read level + 1 at the last level
        nmax = max(len(p) for p in pyramids) + 1
        n = len(pyramids)
        offset = np.zeros((n, nmax), np.int64)
        width = np.ones((n, nmax), np.int64)
        height = np.ones((n, nmax), np.int64)
        scale_u = np.ones((n, nmax), np.float32)
        scale_v = np.ones((n, nmax), np.float32)
        chunks, pos = [], 0
        for k, pyr in enumerate(pyramids):
            h0, w0 = pyr[0].shape
            for level in range(nmax):
                lv = pyr[min(level, len(pyr) - 1)]
                if level < len(pyr):
                    chunks.append(lv.ravel())
                    offset[k, level] = pos
                    pos += lv.size
                else:
                    offset[k, level] = offset[k, len(pyr) - 1]
                height[k, level], width[k, level] = lv.shape
                scale_u[k, level] = lv.shape[1] / w0
                scale_v[k, level] = lv.shape[0] / h0
        return cls(
            texels=np.concatenate(chunks).astype(np.float32),
            offset=offset,
            width=width,
            height=height,
            scale_u=scale_u,
            scale_v=scale_v,
            num_levels=np.array([len(p) for p in pyramids], np.int64),
        )
