"""The dense workspace: undistortion into COLMAP's layout, reading it back, source-view selection
and per-view depth ranges from the sparse points.

Layout (COLMAP's, so that COLMAP's tools open it): ``images/`` (undistorted frames), ``sparse/``
(pinhole cameras, registered poses, sparse points), ``stereo/depth_maps``, ``stereo/normal_maps``
(``{image}.{photometric|geometric}.bin``), ``stereo/patch-match.cfg`` (per reference image, its
source images), ``stereo/fusion.cfg``. Ours in addition: ``stereo/cost_maps`` and
``stereo/previews``.

Pixel convention: COLMAP puts the centre of the top-left pixel at (0.5, 0.5), evdense at (0, 0);
:class:`WorkspaceImage` holds intrinsics in evdense's convention.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from scipy.sparse import csc_matrix

from evdense.camera import Camera
from evdense.formats.files import write_text_atomic
from evdense.log import get_logger
from evdense.mvs.maps_io import read_colmap_array
from evdense.mvs.patchmatch import DepthNormalMap, StereoView

log = get_logger("mvs")

DEPTH_KINDS = ("photometric", "geometric")


@dataclass
class WorkspaceImage:
    """One registered, undistorted image: name, its camera (evdense's pixel convention: pixel
    centres at integer coordinates), and its pose as COLMAP stores it, world-to-camera ``R``
    (3, 3) and ``t`` (3,). :attr:`T_wc` is the same pose camera-to-world, for the stages that
    work in that convention (meshing, texturing)."""

    name: str
    camera: Camera
    R: np.ndarray
    t: np.ndarray

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def height(self) -> int:
        return self.camera.height

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    @property
    def T_wc(self) -> np.ndarray:
        """Camera-to-world ``(4, 4)``: the inverse of ``[R | t]``."""
        T_cw = np.eye(4)
        T_cw[:3, :3], T_cw[:3, 3] = self.R, self.t
        return np.linalg.inv(T_cw)


@dataclass
class Workspace:
    """A dense workspace on disk and its sparse model: images in ``reg_image_ids()`` order, sparse
    points ``(N, 3)`` and, per image, the indices of the points it observes."""

    root: Path
    images: list[WorkspaceImage]
    points: np.ndarray
    observed: list[np.ndarray] = field(default_factory=list)

    def index(self, name: str) -> int:
        for i, im in enumerate(self.images):
            if im.name == name:
                return i
        raise KeyError(f"{self.root}: no image named {name!r} in the workspace")

    # --- paths ------------------------------------------------------------------------
    def image_path(self, name: str) -> Path:
        return self.root / "images" / name

    def map_path(self, what: str, name: str, kind: str) -> Path:
        """``stereo/{what}_maps/{name}.{kind}.bin``; ``what`` in depth, normal, cost."""
        return self.root / "stereo" / f"{what}_maps" / f"{name}.{kind}.bin"

    def preview_stem(self, name: str, kind: str) -> Path:
        return self.root / "stereo" / "previews" / f"{name}.{kind}"

    def has_maps(self, name: str, kind: str) -> bool:
        return all(self.map_path(w, name, kind).is_file() for w in ("depth", "normal", "cost"))

    def read_maps(self, name: str, kind: str) -> DepthNormalMap:
        return DepthNormalMap(
            depth=read_colmap_array(self.map_path("depth", name, kind)),
            normal=read_colmap_array(self.map_path("normal", name, kind)),
            cost=read_colmap_array(self.map_path("cost", name, kind)),
        )

    # --- images -----------------------------------------------------------------------
    def read_rgb(self, name: str) -> np.ndarray:
        """The undistorted image as ``(H, W, 3)`` uint8 (grey images are repeated)."""
        path = self.image_path(name)
        if not path.is_file():
            raise ValueError(f"{path}: image listed in the model is missing from the workspace")
        img = iio.imread(path)
        if img.dtype == np.uint16:
            img = (img // 257).astype(np.uint8)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        return np.ascontiguousarray(img[..., :3].astype(np.uint8))

    def stereo_view(self, name: str) -> StereoView:
        """The image as a :class:`StereoView` (grey levels in [0, 1])."""
        im = self.images[self.index(name)]
        rgb = self.read_rgb(name).astype(np.float32) / 255.0
        grey = rgb @ np.array([0.299, 0.587, 0.114], np.float32)
        if grey.shape != (im.height, im.width):
            raise ValueError(
                f"{self.image_path(name)}: image is {grey.shape[1]}x{grey.shape[0]}, the model says {im.width}x{im.height}"
            )
        return StereoView(image=grey, K=im.K, R=im.R, t=im.t)


def _camera(cam, require_pinhole: bool = True) -> Camera:
    """evdense camera from a pycolmap camera (COLMAP's pixel-centre convention converted by
    :meth:`Camera.from_colmap`); an undistorted workspace holds pinhole cameras only."""
    if require_pinhole and cam.model_name not in ("PINHOLE", "SIMPLE_PINHOLE"):
        raise ValueError(
            f"camera model {cam.model_name} in a dense workspace (expected PINHOLE after undistortion)"
        )
    return Camera.from_colmap(cam.model_name, int(cam.width), int(cam.height), list(cam.params))


def read_workspace(
    root: str | Path, points: bool = True, require_pinhole: bool = True
) -> Workspace:
    """Read the undistorted model of a dense workspace (``root/sparse``): the one reader of a
    workspace's cameras and poses (``points=False`` skips the sparse points and their tracks;
    ``require_pinhole=False`` accepts distorted cameras too).

    Raises ``ValueError`` naming the folder when there is no model or no registered image.
    """
    import pycolmap

    root = Path(root)
    sparse = root / "sparse"
    if not ((sparse / "images.bin").is_file() or (sparse / "images.txt").is_file()):
        raise ValueError(f"{sparse}: no COLMAP model (images.bin / images.txt)")
    rec = pycolmap.Reconstruction(str(sparse))
    ids = list(rec.reg_image_ids())
    if not ids:
        raise ValueError(f"{sparse}: the model has no registered image")
    images = []
    pos = {}
    for k, iid in enumerate(ids):
        im = rec.images[iid]
        cam = rec.cameras[im.camera_id]
        M = np.asarray(im.cam_from_world().matrix(), np.float64)
        images.append(WorkspaceImage(im.name, _camera(cam, require_pinhole), M[:, :3], M[:, 3]))
        pos[iid] = k
    if not points:
        return Workspace(root=root, images=images, points=np.zeros((0, 3)), observed=[])
    pts = []
    obs: list[list[int]] = [[] for _ in ids]
    for j, (_, p) in enumerate(rec.points3D.items()):
        pts.append(np.asarray(p.xyz, np.float64))
        for el in p.track.elements:
            k = pos.get(el.image_id)
            if k is not None:
                obs[k].append(j)
    points = np.array(pts, np.float64).reshape(-1, 3)
    observed = [np.unique(np.array(o, np.int64)) for o in obs]
    return Workspace(root=root, images=images, points=points, observed=observed)


def undistort_to_workspace(
    sparse_dir: str | Path, image_dir: str | Path, root: str | Path, max_image_size: int = -1
) -> Workspace:
    """Undistort the registered images of the COLMAP model ``sparse_dir`` (images read from
    ``image_dir``) into a dense workspace at ``root`` (``images/``, ``sparse/``, ``stereo/``).

    Skipped when ``root/sparse`` already holds a model (resumable); otherwise assembled in
    ``root/.undistort.partial`` and moved into place. ``max_image_size`` > 0 downsizes larger images.
    """
    import pycolmap

    sparse_dir, image_dir, root = Path(sparse_dir), Path(image_dir), Path(root)
    if (root / "sparse" / "images.bin").is_file() and (root / "images").is_dir():
        log.info("%s: undistorted workspace exists; reused", root)
        return read_workspace(root)
    if not ((sparse_dir / "images.bin").is_file() or (sparse_dir / "images.txt").is_file()):
        raise ValueError(f"{sparse_dir}: no COLMAP model (images.bin / images.txt)")
    if not image_dir.is_dir():
        raise ValueError(f"{image_dir}: frames folder not found")
    root.mkdir(parents=True, exist_ok=True)
    tmp = root / ".undistort.partial"
    if tmp.exists():
        shutil.rmtree(tmp)
    opts = pycolmap.UndistortCameraOptions()
    opts.max_image_size = int(max_image_size)
    pycolmap.undistort_images(
        output_path=str(tmp),
        input_path=str(sparse_dir),
        image_path=str(image_dir),
        undistort_options=opts,
    )
    tmp_ws = read_workspace(tmp)
    missing = [im.name for im in tmp_ws.images if not (tmp / "images" / im.name).is_file()]
    if missing:
        shutil.rmtree(tmp, ignore_errors=True)
        raise ValueError(
            f"{image_dir}: {len(missing)} image(s) of the model {sparse_dir} missing or unreadable "
            f"(first: {missing[0]})"
        )
    for name in ("images", "stereo", "sparse"):
        dst = root / name
        if dst.exists():
            shutil.rmtree(dst)
        os.replace(tmp / name, dst)
    shutil.rmtree(tmp, ignore_errors=True)
    ws = read_workspace(root)
    log.info("%s: undistorted %d registered images", root, len(ws.images))
    return ws


# --------------------------------------------------------------------------------------------
# source views and depth ranges
# --------------------------------------------------------------------------------------------
@dataclass
class ViewSelectionConfig:
    """How source views are chosen for each reference view, from the sparse points they share."""

    num_source_views: int = 5
    """Source views per reference view (the best-scoring ones)."""
    min_shared_points: int = 10
    """Least number of sparse points a source view must share with the reference view."""
    min_angle: float = 1.0
    """Shared points whose triangulation angle is below this (degrees) do not count."""
    optimal_angle: float = 5.0
    """A shared point's weight grows as (angle / optimal_angle)^2 up to this angle (degrees);
    smaller favours nearer views."""
    max_angle: float = 60.0
    """Shared points whose triangulation angle exceeds this (degrees) do not count."""
    coverage_decay: float = 0.5
    """Greedy selection: a shared point already seen by ``c`` chosen source views counts
    ``coverage_decay ** c``, so that the sources cover different parts of the reference view
    (1 = no diversity)."""
    depth_percentiles: tuple[float, float] = (1.0, 99.0)
    """Percentiles of the observed points' depths that bound a view's depth range."""
    depth_margin: float = 0.25
    """The depth range is widened by this fraction below and above."""
    min_points_for_range: int = 8
    """With fewer observed points, all sparse points projecting into the view set its range."""


def select_source_views(ws: Workspace, cfg: ViewSelectionConfig) -> list[list[int]]:
    """For every image (in ``ws.images`` order), the indices of its source images, best first.

    A candidate's score sums, over the sparse points it shares with the reference image,
    ``min(angle / optimal_angle, 1)^2 * min(r, 1/r)`` where ``angle`` is the triangulation angle
    and ``r`` the ratio of the point's distances to the two cameras (resolution match); points
    outside ``[min_angle, max_angle]`` count 0. Sources are chosen greedily: each pick multiplies
    the weight of the points it sees by ``coverage_decay``. Candidates sharing fewer than
    ``min_shared_points`` points or scoring 0 are dropped.
    """
    n = len(ws.images)
    centers = np.array([im.center for im in ws.images]).reshape(n, 3)
    rows = np.concatenate(
        [np.full(len(o), i) for i, o in enumerate(ws.observed)] + [np.zeros(0, np.int64)]
    )
    cols = np.concatenate(list(ws.observed) + [np.zeros(0, np.int64)])
    inc = csc_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, len(ws.points)))
    result = []
    for i in range(n):
        pts_i = ws.observed[i]
        sub = inc[:, pts_i].tocoo()
        other = sub.row != i
        if not other.any():
            result.append([])
            continue
        pair_img = sub.row[other]
        pair_pt = pts_i[sub.col[other]]
        pimg = pair_img.astype(np.int64)
        X = ws.points[pair_pt]
        a = X - centers[i]
        b = X - centers[pimg]
        na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        cosang = np.einsum("ij,ij->i", a, b) / np.maximum(na * nb, 1e-12)
        ang = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
        w = np.minimum(ang / cfg.optimal_angle, 1.0) ** 2
        ratio = na / np.maximum(nb, 1e-12)
        w = w * np.minimum(ratio, 1 / np.maximum(ratio, 1e-12))
        w[(ang < cfg.min_angle) | (ang > cfg.max_angle)] = 0
        shared = np.bincount(pimg, minlength=n)
        allowed = shared >= cfg.min_shared_points
        # greedy: points seen by already chosen sources count less
        local = np.searchsorted(pts_i, pair_pt)  # index of the pair's point among pts_i
        seen = np.zeros(len(pts_i))
        chosen: list[int] = []
        for _ in range(cfg.num_source_views):
            score = np.bincount(pimg, weights=w * cfg.coverage_decay ** seen[local], minlength=n)
            score[~allowed] = 0
            score[chosen] = 0
            j = int(np.argmax(score))
            if score[j] <= 0:
                break
            chosen.append(j)
            seen[local[pimg == j]] += 1
        result.append(chosen)
    return result


def depth_range(ws: Workspace, i: int, cfg: ViewSelectionConfig) -> tuple[float, float] | None:
    """Depth range ``(min, max)`` (model units) of image ``i`` from the sparse points it observes
    (percentiles widened by the margin); None when no point lies in front of it."""
    im = ws.images[i]
    pts = ws.points[ws.observed[i]] if i < len(ws.observed) else np.zeros((0, 3))
    z = (pts @ im.R.T + im.t)[:, 2] if len(pts) else np.zeros(0)
    z = z[z > 0]
    if len(z) < cfg.min_points_for_range and len(ws.points):
        Xc = ws.points @ im.R.T + im.t
        front = Xc[:, 2] > 0
        uv = Xc[front, :2] / Xc[front, 2:3] @ im.K[:2, :2].T + im.K[:2, 2]
        inside = (
            (uv[:, 0] >= 0)
            & (uv[:, 0] <= im.width - 1)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] <= im.height - 1)
        )
        z = Xc[front, 2][inside]
    if len(z) == 0:
        return None
    lo, hi = np.percentile(z, cfg.depth_percentiles)
    lo, hi = lo * (1 - cfg.depth_margin), hi * (1 + cfg.depth_margin)
    lo = max(lo, 1e-6 * hi, 1e-9)
    if hi <= lo * 1.01:
        hi = lo * 1.5
    return float(lo), float(hi)


def write_patch_match_cfg(ws: Workspace, sources: list[list[int]]) -> None:
    """Write ``stereo/patch-match.cfg`` (reference name, then its source names, comma separated)
    and ``stereo/fusion.cfg`` (all names) in COLMAP's format."""
    stereo = ws.root / "stereo"
    stereo.mkdir(parents=True, exist_ok=True)
    lines = []
    for im, src in zip(ws.images, sources, strict=True):
        lines.append(im.name)
        lines.append(", ".join(ws.images[j].name for j in src))
    write_text_atomic(stereo / "patch-match.cfg", "\n".join(lines) + "\n")
    write_text_atomic(stereo / "fusion.cfg", "".join(im.name + "\n" for im in ws.images))


def input_fingerprint(sparse_dir: Path, image_dir: Path, cfg: object) -> str:
    """SHA-1 over the sparse model's files, the images' bytes and the MVS config: what the
    workspace's maps were computed from."""
    import hashlib

    h = hashlib.sha1(repr(cfg).encode())
    for p in sorted(Path(sparse_dir).glob("*")) + sorted(Path(image_dir).glob("*.png")):
        if p.is_file():
            h.update(p.name.encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def discard_stale_workspace(out_dir: Path, fingerprint: str) -> bool:
    """Remove the undistorted images and maps of ``out_dir`` when they were made from other
    inputs (another fingerprint, or none recorded); True when something was removed. Resuming
    must only ever reuse maps of the same inputs."""
    stamp = out_dir / "inputs.sha1"
    parts = [out_dir / n for n in ("images", "sparse", "stereo")]
    if stamp.is_file() and stamp.read_text().strip() == fingerprint:
        return False
    stale = [p for p in parts if p.exists()]
    for p in stale:
        shutil.rmtree(p)
    if stale:
        log.info("%s: workspace made from other inputs; discarded", out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stamp.write_text(fingerprint + "\n")
    return bool(stale)
