"""A pool of photographs for the planar training generator (``train.data.picture_dirs``).

Usage: .venv/bin/python benchmarks/make_photo_pool.py [--out results/photos] [--collages 600]

Made from three Debian packages fetched from the package registry with ``apt-get download``
(nothing is installed):

- ``opencv-doc``: the photographs of OpenCV's sample data (``examples/data``: offices, a building,
  fruit, faces, a street, graffiti, boxes on a table; the chessboard, logo and synthetic images
  are left out) -> ``OUT/opencv``;
- ``ukui-wallpapers`` and ``lomiri-wallpapers``: desktop backgrounds, mostly photographs ->
  ``OUT/wallpapers``;
- ``tuxpaint-stamps-default``: about 550 cut-out photographs and drawings of objects (animals,
  food, household things, vehicles, plants; letters and symbols left out), each with an alpha
  mask -> ``OUT/collages``: ``--collages`` pictures of 3-9 such objects laid over one another on a
  backdrop, which is a plain wall with a gentle shading gradient (half of them) or a blurred
  photograph of the two other folders. Each object gets a lighting gain of its own, so objects and
  walls meet at unrelated levels, as in a room, and plain regions come at every level.

Idempotent: a pool whose ``OUT/.complete`` exists is left as it is; a pool is built aside and moved
into place only when whole. The licences of the packages are copied into each folder.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from scipy.ndimage import gaussian_filter, zoom

PACKAGES = ("opencv-doc", "ukui-wallpapers", "lomiri-wallpapers", "tuxpaint-stamps-default")
# OpenCV sample images that are not photographs (charts, logos, renders, text, masks, paintings)
NOT_PHOTOS = (
    "chessboard", "logo", "digits", "sudoku", "gradient", "notes", "ml.png", "mask", "cards",
    "detect_blob", "ellipses", "pic", "imageText", "alphabet", "Blender", "starry_night", "aloeGT",
    "box.png", "left0", "left1", "right0", "right1", "WindowsLogo", "LinuxLogo", "board",
    "chicky", "blox", "smarties", "ela_",
)  # fmt: skip
STAMP_SKIP = ("symbols", "seasonal")  # mostly letters, signs and drawings
SIZE = 512


def gray(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An image as grey float32 in [0, 1] and its alpha (ones when it has none)."""
    img = np.asarray(img)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    img = img.astype(np.float32) / scale
    if img.ndim == 2:
        img = img[..., None]
    c = img.shape[2]
    alpha = img[..., 3] if c == 4 else img[..., 1] if c == 2 else np.ones(img.shape[:2], np.float32)
    rgb = img[..., :3] if c >= 3 else np.repeat(img[..., :1], 3, axis=2)
    return rgb @ np.array([0.2125, 0.7154, 0.0721], np.float32), alpha


def fit(img: np.ndarray, size: int) -> np.ndarray:
    """Centre-crop to a square and resample to ``size`` x ``size``."""
    h, w = img.shape[:2]
    s = min(h, w)
    img = img[(h - s) // 2 : (h - s) // 2 + s, (w - s) // 2 : (w - s) // 2 + s]
    return zoom(img, size / s, order=1)[:size, :size]


def save(path: Path, img: np.ndarray) -> None:
    iio.imwrite(path, (np.clip(img, 0, 1) * 255).round().astype(np.uint8))


def backdrop(rng: np.random.Generator, photos: list[np.ndarray]) -> np.ndarray:
    if photos and rng.random() < 0.5:
        img = photos[rng.integers(len(photos))]
        img = gaussian_filter(img, rng.uniform(2, 12))  # out of focus behind the objects
        return np.clip(rng.uniform(0.4, 1.0) * img, 0, 1)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE] / SIZE
    ang = rng.uniform(0, 2 * np.pi)
    ramp = np.cos(ang) * xx + np.sin(ang) * yy
    level = rng.uniform(0.1, 0.9)
    return np.clip(level * (1 + rng.uniform(-0.3, 0.3) * (ramp - ramp.mean())), 0, 1)


def collage(rng: np.random.Generator, stamps: list[Path], photos: list[np.ndarray]) -> np.ndarray:
    canvas = backdrop(rng, photos).astype(np.float32)
    for _ in range(int(rng.integers(3, 10))):
        value, alpha = gray(iio.imread(stamps[rng.integers(len(stamps))]))
        side = int(SIZE * rng.uniform(0.12, 0.6))
        f = side / max(value.shape)
        value, alpha = zoom(value, f, order=1), zoom(alpha, f, order=1)
        if rng.random() < 0.5:
            value, alpha = value[:, ::-1], alpha[:, ::-1]
        h, w = value.shape
        y0, x0 = rng.integers(-h // 3, SIZE - 2 * h // 3), rng.integers(-w // 3, SIZE - 2 * w // 3)
        ys, xs = slice(max(y0, 0), min(y0 + h, SIZE)), slice(max(x0, 0), min(x0 + w, SIZE))
        v = value[ys.start - y0 : ys.stop - y0, xs.start - x0 : xs.stop - x0]
        a = np.clip(alpha[ys.start - y0 : ys.stop - y0, xs.start - x0 : xs.stop - x0], 0, 1)
        lit = np.clip(v * rng.uniform(0.3, 1.3), 0, 1)  # each object lit on its own
        canvas[ys, xs] = a * lit + (1 - a) * canvas[ys, xs]
    return canvas


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", default="results/photos")
    ap.add_argument("--collages", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    out = Path(args.out)
    if (out / ".complete").is_file():
        print(f"photo pool: {out} already made ({(out / '.complete').read_text().strip()})")
        return
    part = out.with_name(out.name + ".partial")
    shutil.rmtree(part, ignore_errors=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        subprocess.run(["apt-get", "download", *PACKAGES], cwd=work, check=True,
                       stdout=subprocess.DEVNULL)  # fmt: skip
        versions = []
        for deb in sorted(work.glob("*.deb")):
            subprocess.run(["dpkg-deb", "-x", str(deb), str(work / "x")], check=True)
            info = subprocess.run(["dpkg-deb", "-f", str(deb), "Package", "Version"],
                                  check=True, capture_output=True, text=True).stdout  # fmt: skip
            versions.append(" ".join(info.split()))
        x = work / "x" / "usr" / "share"
        photos: list[np.ndarray] = []
        for sub, files in (
            ("opencv", sorted((x / "doc/opencv-doc/examples/data").glob("*"))),
            ("wallpapers", sorted((x / "backgrounds").rglob("*"))),
        ):
            (part / sub).mkdir(parents=True)
            for f in files:
                if f.suffix.lower() not in (".jpg", ".png") or any(s in f.name for s in NOT_PHOTOS):
                    continue
                value, _ = gray(iio.imread(f))
                if min(value.shape) < 200:
                    continue
                photos.append(fit(value, SIZE))
                save(part / sub / f"{f.stem}.png", photos[-1])
        stamps = sorted(
            f
            for f in (x / "tuxpaint/stamps").rglob("*.png")
            if not any(skip in f.parts for skip in STAMP_SKIP)
        )
        if not photos or not stamps:
            raise SystemExit("photo pool: the packages held no photograph or no stamp")
        (part / "collages").mkdir()
        rng = np.random.default_rng(args.seed)
        for k in range(args.collages):
            save(part / "collages" / f"collage_{k:04d}.png", collage(rng, stamps, photos))
        for pkg, sub in zip(
            PACKAGES, ("opencv", "wallpapers", "wallpapers", "collages"), strict=True
        ):
            shutil.copy(x / "doc" / pkg / "copyright", part / sub / f"COPYRIGHT.{pkg}")
        summary = (f"{len(photos)} photographs, {args.collages} collages of {len(stamps)} stamps; "
                   + "; ".join(versions))  # fmt: skip
        (part / ".complete").write_text(summary + "\n")
    shutil.rmtree(out, ignore_errors=True)
    part.rename(out)
    print(f"photo pool: {out} ({summary})")


if __name__ == "__main__":
    main()
