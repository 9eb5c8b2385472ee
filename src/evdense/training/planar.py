"""Planar training scenes: textured layers sliding over each other, rendered by warping.

The 3D scenes of :mod:`evdense.training.data` give parallax but cost a ray cast per render and
offer a handful of textures. This generator gives the other half of a training set: many
textures and motions, cheaply. A scene is a stack of layers, each a grey texture seen through its
own smooth random homography of time:

- a background layer that always covers the view (the camera's own motion: pan, tilt, roll, zoom
  and a little perspective), optionally carrying a lit region (a soft-edged blob or half-plane
  whose radiance is the sequence's dynamic range times brighter: high dynamic range up to 10^5);
- zero to four foreground objects (a texture cut out by an ellipse, polygon or rectangle with an
  anti-aliased edge) that move on their own, so edges occlude and disocclude what is behind them.

Textures (:func:`random_texture`) cover what the reconstruction meets in the wild: natural
pictures (every one that scikit-image and Matplotlib ship, but those kept for the held-out split),
dead leaves and 1/f noise (natural-image statistics), flat and gradient surfaces with a few shapes
or none (the low-texture walls and floors where a recurrent network must hold its state for
hundreds of windows), text in several fonts, gratings, and mosaics of all of these (textured dead
leaves, :func:`_mosaic_texture`; drawn only when ``train.data.planar_textures`` asks). Time is
warped by a random speed profile, with near pauses, so windows cover very different durations and
noise shares.

Everything is drawn from one ``numpy.random.Generator``: a sequence is reproducible from its seed.
Rendering is supersampled 2x and box-filtered (no aliasing flicker that a real lens would blur).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from evdense.sim.textures import dead_leaves, dead_leaves_labels, spectral_noise

HELDOUT_PICTURES = ("moon", "text", "coins", "page", "cell", "immunohistochemistry", "checkerboard")
"""skimage.data pictures reserved for the held-out split (never used by this generator)."""

TRAIN_PICTURES = (
    "skimage:astronaut",
    "skimage:brick",
    "skimage:camera",
    "skimage:chelsea",
    "skimage:coffee",
    "skimage:grass",
    "skimage:gravel",
    "skimage:rocket",
    "skimage:hubble_deep_field",
    "skimage:retina",
    "skimage:clock",
    "skimage:horse",
    "skimage:logo",
    "skimage:microaneurysms",
    "skimage:shepp_logan_phantom",
    "skimage-file:color.png",
    "skimage-file:motorcycle_left.png",
    "skimage-file:motorcycle_right.png",
    "skimage-file:lfw_subset.npy",
    "mpl:grace_hopper.jpg",
    "mpl:Minduka_Present_Blue_Pack.png",
    "mpl:logo2.png",
    "mpl:topobathy.npz",
    "mpl:jacksboro_fault_dem.npz",
    "mpl:s1045.ima.gz",
)
"""Pictures the planar generator draws from (all installed with scikit-image and Matplotlib)."""

PICTURE_SUFFIXES = (".jpg", ".jpeg", ".png")
"""Image files :func:`find_pictures` takes from a folder."""

MAX_FILE_PICTURE_PX = 1024
"""Longest side a ``file:`` picture is kept at: :func:`random_texture` scales a picture to at most
twice the 512-texel texture side, so a larger one would only cost memory in the cache."""

TEXTURE_KINDS = ("picture", "dead_leaves", "noise", "flat", "shapes", "text", "grating", "mosaic")


@dataclass
class PlanarConfig:
    """How planar scenes are drawn (part of ``train.data``)."""

    texture_weights: dict[str, float] = field(
        default_factory=lambda: {
            "picture": 0.3,
            "dead_leaves": 0.15,
            "noise": 0.12,
            "flat": 0.13,
            "shapes": 0.12,
            "text": 0.1,
            "grating": 0.08,
        }
    )
    """Relative frequency of each texture kind (:data:`TEXTURE_KINDS`; a kind left out is not drawn)."""
    pictures: tuple[str, ...] = TRAIN_PICTURES
    """Pictures of the ``picture`` kind (names as :func:`load_picture` takes them)."""
    max_objects: int = 4
    """Most foreground objects in a scene."""
    supersample: int = 2
    """Renders are made at this many times the resolution, then box-filtered."""


# ---------------------------------------------------------------------------------------------
# Pictures
# ---------------------------------------------------------------------------------------------


def _to_gray(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.dtype == bool:
        img = img.astype(np.float32)
    elif np.issubdtype(img.dtype, np.integer):
        img = img.astype(np.float32) / max(1, int(img.max()))
    img = img.astype(np.float32)
    if img.ndim == 3:
        if img.shape[2] >= 3:
            img = img[..., :3] @ np.array([0.2125, 0.7154, 0.0721], np.float32)
        else:
            img = img[..., 0]
    lo, hi = np.percentile(img, [0.5, 99.5])
    return np.clip((img - lo) / max(hi - lo, 1e-6), 0, 1).astype(np.float32)


@functools.lru_cache(maxsize=16)
def find_pictures(folders: tuple[str, ...]) -> tuple[str, ...]:
    """``file:`` names of the images (:data:`PICTURE_SUFFIXES`) anywhere below each folder, sorted
    so that a draw does not depend on the file system's order. A folder that is missing or holds
    no image raises ``ValueError`` naming it."""
    names: list[str] = []
    for folder in folders:
        root = Path(folder)
        if not root.is_dir():
            raise ValueError(f"train.data.picture_dirs: {root} is not a folder")
        found = sorted(
            str(f) for f in root.rglob("*") if f.suffix.lower() in PICTURE_SUFFIXES and f.is_file()
        )
        if not found:
            raise ValueError(
                f"train.data.picture_dirs: {root} holds no {'/'.join(PICTURE_SUFFIXES)} image"
            )
        names += [f"file:{f}" for f in found]
    return tuple(names)


@functools.lru_cache(maxsize=64)
def load_picture(name: str) -> np.ndarray:
    """A picture as grey ``(h, w)`` float32 in [0, 1] (display-encoded): one of
    :data:`TRAIN_PICTURES`, or ``file:PATH`` for any image file."""
    kind, _, ref = name.partition(":")
    if kind == "file":
        import imageio.v3 as iio

        try:
            img = _to_gray(iio.imread(ref))
        except Exception as exc:
            raise ValueError(f"{ref}: not a readable picture ({exc})") from exc
        if max(img.shape) > MAX_FILE_PICTURE_PX:  # the generator never samples finer than this
            from skimage.transform import rescale

            img = rescale(img, MAX_FILE_PICTURE_PX / max(img.shape), anti_aliasing=True)
        return img.astype(np.float32)
    if kind == "skimage":
        import skimage.data

        return _to_gray(getattr(skimage.data, ref)())
    if kind == "skimage-file":
        import skimage.data

        path = Path(skimage.data.__file__).parent / ref
        if ref.endswith(".npy"):  # a stack of small faces: tile them into one picture
            faces = np.load(path)[:64]
            n = int(np.sqrt(len(faces)))
            faces = faces[: n * n].reshape(n, n, *faces.shape[1:])
            return _to_gray(np.concatenate(np.concatenate(faces, 1), 1))
        import imageio.v3 as iio

        return _to_gray(iio.imread(path))
    if kind == "mpl":
        import matplotlib.cbook as cbook

        if ref.endswith(".npz"):  # elevation models: hill shading of the relief
            with np.load(cbook.get_sample_data(ref, asfileobj=False)) as d:
                z = np.asarray(d["elevation"] if "elevation" in d.files else d[d.files[0]])
            gy, gx = np.gradient(z.astype(np.float64))
            shade = 0.6 * gx - 0.8 * gy
            return _to_gray(np.clip(shade, -3 * shade.std(), 3 * shade.std()))
        if ref.endswith(".ima.gz"):  # a 256x256 uint16 MRI slice
            import gzip

            with gzip.open(cbook.get_sample_data(ref, asfileobj=False)) as f:
                raw = f.read()
            return _to_gray(np.frombuffer(raw, np.uint16).reshape(256, 256).astype(np.float32))
        import imageio.v3 as iio

        return _to_gray(iio.imread(cbook.get_sample_data(ref, asfileobj=False)))
    raise ValueError(f"unknown picture source {name!r}")


# ---------------------------------------------------------------------------------------------
# Procedural textures
# ---------------------------------------------------------------------------------------------


def _smooth_field(rng: np.random.Generator, size: int, beta: float = 4.0) -> np.ndarray:
    """A very smooth random field in [0, 1] (low-frequency 1/f^beta noise)."""
    f = spectral_noise(size, beta, 1.0, 1.0, rng)
    return (f - f.min()) / max(float(np.ptp(f)), 1e-6)


def _soft_mask(rng: np.random.Generator, size: int, kind: str | None = None) -> np.ndarray:
    """An anti-aliased shape mask ``(size, size)`` in [0, 1]: ellipse, polygon or rectangle."""
    from skimage.draw import polygon as draw_polygon

    ss = 4
    n = size * ss
    kind = kind or str(rng.choice(["ellipse", "polygon", "rectangle"]))
    m = np.zeros((n, n), np.float32)
    c = n / 2
    if kind == "ellipse":
        yy, xx = np.mgrid[:n, :n] + 0.5
        a, b = rng.uniform(0.3, 0.48, 2) * n
        th = rng.uniform(0, np.pi)
        u = (xx - c) * np.cos(th) + (yy - c) * np.sin(th)
        v = -(xx - c) * np.sin(th) + (yy - c) * np.cos(th)
        m[(u / a) ** 2 + (v / b) ** 2 <= 1] = 1
    else:
        k = 4 if kind == "rectangle" else int(rng.integers(3, 9))
        ang = np.sort(rng.uniform(0, 2 * np.pi, k)) if kind == "polygon" else (
            np.array([0.25, 0.75, 1.25, 1.75]) * np.pi + rng.uniform(0, np.pi))  # fmt: skip
        rad = rng.uniform(0.25, 0.48, k) * n if kind == "polygon" else np.full(k, 0.47 * n)
        rr, cc = draw_polygon(c + rad * np.sin(ang), c + rad * np.cos(ang), (n, n))
        m[rr, cc] = 1
    return m.reshape(size, ss, size, ss).mean((1, 3))


def _text_texture(rng: np.random.Generator, size: int, low: float, high: float) -> np.ndarray:
    import matplotlib
    from PIL import Image, ImageDraw, ImageFont

    fonts = sorted((Path(matplotlib.get_data_path()) / "fonts" / "ttf").glob("DejaVu*.ttf"))
    bg = float(rng.uniform(low, high))
    img = Image.new("F", (size, size), bg)
    draw = ImageDraw.Draw(img)
    letters = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789 .,;:!?-+=()"
    y = float(rng.uniform(-10, 10))
    while y < size:
        fs = int(rng.integers(10, 70))
        font = ImageFont.truetype(str(fonts[int(rng.integers(len(fonts)))]), fs)
        line = "".join(rng.choice(list(letters), int(rng.integers(5, 40))))
        ink = float(rng.uniform(low, high))
        if abs(ink - bg) < 0.15:
            ink = low if bg > (low + high) / 2 else high
        draw.text((float(rng.uniform(-20, 10)), y), line, fill=ink, font=font)
        y += fs * float(rng.uniform(1.0, 2.5))
    return np.asarray(img, np.float32)


def _mosaic_texture(
    rng: np.random.Generator, size: int, weights: dict[str, float], pictures: tuple[str, ...]
) -> np.ndarray:
    """Textured dead leaves: the occlusion layout of a dead-leaves image whose disks are filled, each
    with its own level and contrast, from a few textures of the other kinds.

    A few dozen pictures cannot give the variety of a natural-image corpus; their pieces can be
    recombined without end into scenes with natural-image structure: occluding edges at every
    scale, plain regions of unrelated levels side by side, and texture inside objects.
    """
    inner = {k: w for k, w in weights.items() if k != "mosaic" and w > 0}
    inner.setdefault("flat", 0.1)
    n_fills = int(rng.integers(3, 7))
    fills = np.stack([random_texture(rng, size, inner, pictures) for _ in range(n_fills)])
    fills -= fills.mean((1, 2), keepdims=True)
    labels, _ = dead_leaves_labels(size, float(rng.uniform(4, 16)), float(rng.uniform(60, 300)),
                                   float(rng.uniform(2.0, 3.0)), rng)  # fmt: skip
    n = int(labels.max()) + 1
    which = rng.integers(0, len(fills), n)
    level = rng.uniform(0.03, 1.0, n).astype(np.float32)
    gain = np.exp(rng.uniform(np.log(0.3), np.log(1.5), n)).astype(np.float32)
    lab = np.maximum(labels, 0)
    fill = np.take_along_axis(fills, which[lab][None], 0)[0]  # each texel from its disk's fill
    tex = np.where(labels >= 0, level[lab] + gain[lab] * fill, np.float32(0.5))
    return np.clip(tex, 0.01, 1).astype(np.float32)


def random_texture(
    rng: np.random.Generator,
    size: int,
    weights: dict[str, float],
    pictures: tuple[str, ...] = TRAIN_PICTURES,
) -> np.ndarray:
    """A random grey reflectance texture ``(size, size)`` float32 in (0, 1] (see module docstring);
    the ``picture`` kind draws from ``pictures``."""
    kinds = [k for k in TEXTURE_KINDS if k in weights]  # a fixed order: the draw ignores dict order
    p = np.array([weights[k] for k in kinds], np.float64)
    kind = str(rng.choice(kinds, p=p / p.sum()))
    low = float(rng.uniform(0.02, 0.3))
    high = float(rng.uniform(max(low + 0.15, 0.45), 1.0))
    if kind == "picture":
        from skimage.transform import rescale, rotate

        pic = load_picture(str(rng.choice(pictures)))
        scale = float(np.exp(rng.uniform(np.log(0.35), np.log(2.0))))
        pic = rescale(pic, scale * size / max(pic.shape), anti_aliasing=scale < 1)
        if rng.random() < 0.5:
            pic = rotate(pic, float(rng.uniform(0, 360)), mode="reflect")
        reps = int(np.ceil(size / min(pic.shape))) + 1
        big = np.tile(np.concatenate([pic, pic[::-1]], 0), (reps, reps))  # mirrored tiling
        big = np.concatenate([big, big[:, ::-1]], 1)
        y0 = int(rng.integers(0, big.shape[0] - size + 1))
        x0 = int(rng.integers(0, big.shape[1] - size + 1))
        tex = big[y0 : y0 + size, x0 : x0 + size]
        tex = tex ** float(np.exp(rng.uniform(np.log(0.5), np.log(2.2))))  # display -> linear-ish
        if rng.random() < 0.2:
            tex = 1 - tex
    elif kind == "dead_leaves":
        tex = dead_leaves(size, float(rng.uniform(1.5, 6)), float(rng.uniform(20, 200)),
                          float(rng.uniform(2.2, 3.5)), rng)  # fmt: skip
    elif kind == "noise":
        tex = spectral_noise(size, float(rng.uniform(1.5, 4.0)), 1.0, float(rng.uniform(0.5, 3)),
                             rng)  # fmt: skip
    elif kind == "flat":  # low texture: a plain or gently shaded surface, faint noise
        tex = np.full((size, size), float(rng.uniform(0.2, 0.9)), np.float32)
        if rng.random() < 0.7:
            tex = tex * (1 + float(rng.uniform(0.1, 0.8)) * (_smooth_field(rng, size) - 0.5))
        tex = tex * (
            1 + float(rng.uniform(0, 0.06)) * (spectral_noise(size, 2.0, 2.0, 1.0, rng) - 0.5)
        )
        return np.clip(tex, 0.01, 1).astype(np.float32)
    elif kind == "shapes":  # a few shapes on a flat background (as the ECD shapes scene)
        tex = np.full((size, size), float(rng.uniform(low, high)), np.float32)
        for _ in range(int(rng.integers(1, 9))):
            s = int(rng.integers(size // 16, size // 3))
            y0, x0 = rng.integers(0, size - s, 2)
            m = _soft_mask(rng, s)
            v = float(rng.uniform(low, high))
            tex[y0 : y0 + s, x0 : x0 + s] = tex[y0 : y0 + s, x0 : x0 + s] * (1 - m) + v * m
        return np.clip(tex, 0.01, 1).astype(np.float32)
    elif kind == "text":
        return np.clip(_text_texture(rng, size, low, high), 0.01, 1).astype(np.float32)
    elif kind == "mosaic":
        return _mosaic_texture(rng, size, weights, pictures)
    else:  # grating: sine or square wave of random period and orientation
        yy, xx = np.mgrid[:size, :size].astype(np.float32)
        th = float(rng.uniform(0, np.pi))
        period = float(np.exp(rng.uniform(np.log(12), np.log(size / 2))))
        ph = (xx * np.cos(th) + yy * np.sin(th)) * 2 * np.pi / period
        tex = 0.5 + 0.5 * np.sin(ph)
        if rng.random() < 0.5:
            tex = (tex > 0.5).astype(np.float32)
    tex = np.asarray(tex, np.float32)
    lo_, hi_ = float(tex.min()), float(tex.max())
    tex = (tex - lo_) / max(hi_ - lo_, 1e-6)
    return (low + (high - low) * tex).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# Motion: a smooth random homography of time
# ---------------------------------------------------------------------------------------------


@dataclass
class LayerMotion:
    """Image-plane motion of a layer: similarity plus perspective, each a drift plus sinusoids.

    Parameters at time ``u`` (warped time, see :class:`TimeWarp`): translation ``(tx, ty)`` in
    pixels, rotation in radians, log scale and two perspective terms; ``u`` runs over [0, 1].
    """

    drift: np.ndarray  # (6,)
    amp: np.ndarray  # (K, 6)
    freq: np.ndarray  # (K, 6) cycles per unit of u
    phase: np.ndarray  # (K, 6)

    def params(self, u: float) -> np.ndarray:
        s = np.sin(2 * np.pi * self.freq * u + self.phase) - np.sin(self.phase)
        return self.drift * u + (self.amp * s).sum(0)


def random_motion(
    rng: np.random.Generator, width: int, extent: float, perspective: bool
) -> LayerMotion:
    """A motion whose translation travels about ``extent`` image widths over the sequence."""
    k = 3
    travel = extent * width
    drift = np.zeros(6)
    drift[:2] = rng.normal(0, 1, 2) * travel * 0.6
    drift[2] = rng.normal(0, 0.4)
    drift[3] = rng.normal(0, 0.2)
    amp = np.zeros((k, 6))
    amp[:, :2] = rng.normal(0, 1, (k, 2)) * travel * 0.25
    amp[:, 2] = rng.normal(0, 0.15, k)
    amp[:, 3] = rng.normal(0, 0.08, k)
    if perspective:
        amp[:, 4:] = rng.normal(0, 0.15, (k, 2)) / width
    freq = rng.uniform(0.3, 3.0, (k, 6))
    phase = rng.uniform(0, 2 * np.pi, (k, 6))
    return LayerMotion(drift, amp, freq, phase)


@dataclass
class TimeWarp:
    """Map from seconds to motion time ``u`` (1 at the profile's end): a random speed profile with slow spells."""

    t_grid: np.ndarray
    u_grid: np.ndarray

    @classmethod
    def random(cls, rng: np.random.Generator, duration: float, pauses: bool) -> TimeWarp:
        n = 512
        t = np.linspace(0, duration, n)
        # log speed: smooth noise; optional near-stops
        logv = np.zeros(n)
        for _ in range(4):
            logv += rng.normal(0, 0.5) * np.sin(2 * np.pi * rng.uniform(0.5, 6) * t / duration
                                                 + rng.uniform(0, 2 * np.pi))  # fmt: skip
        v = np.exp(logv)
        if pauses:
            for _ in range(int(rng.integers(1, 4))):
                c, w = rng.uniform(0, duration), rng.uniform(0.02, 0.12) * duration
                v *= 1 - 0.98 * np.exp(-0.5 * ((t - c) / (w / 2)) ** 2)
        u = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        return cls(t, u / u[-1])

    def __call__(self, t: float) -> float:
        """``u`` at ``t`` seconds; past the profile's end the motion goes on at its mean speed."""
        end = float(self.t_grid[-1])
        if t > end:
            return 1.0 + (t - end) / end
        return float(np.interp(t, self.t_grid, self.u_grid))


# ---------------------------------------------------------------------------------------------
# The scene
# ---------------------------------------------------------------------------------------------


@dataclass
class _Layer:
    tex: torch.Tensor  # (1, C, h, w): value (premultiplied) [, alpha] [, light]
    motion: LayerMotion
    center: np.ndarray  # texture-pixel position of the view centre at u = 0
    scale: float  # texture pixels per supersampled image pixel at u = 0
    background: bool


class PlanarScene:
    """A random planar scene rendered as linear radiance ``(height, width)`` at any time."""

    def __init__(
        self,
        rng: np.random.Generator,
        width: int,
        height: int,
        duration: float,
        dynamic_range: float = 1.0,
        conf: PlanarConfig | None = None,
    ) -> None:
        conf = conf or PlanarConfig()
        self.width, self.height, self.ss = width, height, conf.supersample
        self.dynamic_range = float(dynamic_range)
        W, H = width * self.ss, height * self.ss
        self.warp = TimeWarp.random(rng, duration, pauses=rng.random() < 0.3)
        extent = float(np.exp(rng.uniform(np.log(0.3), np.log(3.0))))
        size = 512
        layers: list[_Layer] = []
        bg = random_texture(rng, size, conf.texture_weights, conf.pictures)
        chans = [bg]
        if self.dynamic_range > 1:
            light = _light_mask(rng, size)
            chans.append(light)
        tex = torch.from_numpy(np.stack(chans))[None]
        # background texel scale: the view (plus its travel) fits in the texture, mirrored beyond
        bscale = float(rng.uniform(0.25, 0.7)) * size / W
        layers.append(_Layer(tex, random_motion(rng, W, extent, True), np.array([size / 2] * 2),
                             bscale, True))  # fmt: skip
        for _ in range(int(rng.integers(0, conf.max_objects + 1))):
            osize = 256
            t = random_texture(rng, osize, conf.texture_weights, conf.pictures)
            m = _soft_mask(rng, osize)
            otex = torch.from_numpy(np.stack([t * m, m]))[None]
            oscale = float(np.exp(rng.uniform(np.log(0.8), np.log(5.0)))) * osize / W
            c = (
                np.array([osize / 2, osize / 2])
                + rng.uniform(-0.5, 0.5, 2) * np.array([W, H]) * oscale
            )
            layers.append(_Layer(otex, random_motion(rng, W, extent * float(rng.uniform(0.3, 1.5)),
                                                     False), c, oscale, False))  # fmt: skip
        self.layers = layers
        ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64) + 0.5 - H / 2,
                                torch.arange(W, dtype=torch.float64) + 0.5 - W / 2, indexing="ij")  # fmt: skip
        self._pix = torch.stack([xs, ys, torch.ones_like(xs)], -1).reshape(-1, 3)  # (HW, 3)

    def _grid(self, layer: _Layer, u: float) -> torch.Tensor:
        tx, ty, rot, logs, px, py = layer.motion.params(u)
        s = layer.scale * float(np.exp(logs))
        c, sn = np.cos(rot), np.sin(rot)
        # image pixel (centred) -> texture pixel
        A = np.array([[s * c, -s * sn, layer.center[0] + tx * layer.scale],
                      [s * sn, s * c, layer.center[1] + ty * layer.scale],
                      [px, py, 1.0]])  # fmt: skip
        q = self._pix @ torch.from_numpy(A.T)
        q = q[:, :2] / q[:, 2:3].clamp_min(1e-3)
        h, w = layer.tex.shape[-2:]
        g = torch.stack([q[:, 0] / w * 2 - 1, q[:, 1] / h * 2 - 1], -1)
        return g.reshape(1, self.height * self.ss, self.width * self.ss, 2).float()

    def radiance(self, t: float) -> np.ndarray:
        """Linear radiance ``(height, width)`` float64 at time ``t`` seconds (> 0)."""
        u = self.warp(t)
        img = None
        for layer in self.layers:
            g = self._grid(layer, u)
            if layer.background:
                # mirror beyond the texture: the background always covers the view
                s = F.grid_sample(layer.tex, g, mode="bilinear", padding_mode="reflection",
                                  align_corners=False)  # fmt: skip
                img = s[:, :1]
                if s.shape[1] > 1:
                    img = img * (1 + (self.dynamic_range - 1) * s[:, 1:2])
            else:
                s = F.grid_sample(layer.tex, g, mode="bilinear", padding_mode="zeros",
                                  align_corners=False)  # fmt: skip
                img = img * (1 - s[:, 1:2]) + s[:, :1]
        img = F.avg_pool2d(img, self.ss)
        return img[0, 0].double().numpy().clip(1e-4, None)


def _light_mask(rng: np.random.Generator, size: int) -> np.ndarray:
    """Where the lit part of an HDR background is: a soft-edged half-plane, blob or window."""
    from scipy.ndimage import gaussian_filter

    kind = rng.choice(["half", "blob", "window"])
    if kind == "half":
        yy, xx = np.mgrid[:size, :size] - size / 2
        th = rng.uniform(0, 2 * np.pi)
        m = ((xx * np.cos(th) + yy * np.sin(th)) > rng.uniform(-0.2, 0.3) * size).astype(np.float32)
    elif kind == "blob":
        m = (_smooth_field(rng, size, 3.0) > rng.uniform(0.5, 0.7)).astype(np.float32)
    else:
        m = np.zeros((size, size), np.float32)
        s = int(rng.integers(size // 5, size // 2))
        y0, x0 = rng.integers(0, size - s, 2)
        m[y0 : y0 + s, x0 : x0 + s] = _soft_mask(rng, s, "rectangle")
    return gaussian_filter(m, float(rng.uniform(0.5, 4))).astype(np.float32)
