"""Fusion of filtered depth maps into one dense point cloud with normals and colours.

Two methods:

- ``voxel`` (ours): every kept depth-map pixel is back-projected to the world; points are merged
  per voxel (mean position, mean normal, mean colour) and the views that contributed are recorded.
  The per-view filter (:func:`evdense.mvs.patchmatch.filter_depth_map`) has already required
  agreement with other views' depth maps. Memory is bounded: views are added in batches and
  merged as they come.
- ``colmap``: ``pycolmap.stereo_fusion`` on the workspace (COLMAP's graph traversal over
  consistent pixels; CPU). Note that COLMAP's fusion back-projects pixel ``(col, row)`` with the
  model's intrinsics as if its centre were at ``(col, row)``, half a pixel off COLMAP's own image
  convention; our maps follow the images' convention.

Both end with statistical outlier removal (open3d) and write a PLY in COLMAP's layout (float
x y z nx ny nz, uchar red green blue) plus ``<ply>.vis`` (COLMAP's visibility file; image indices
in ``Reconstruction.reg_image_ids()`` order).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from evdense.formats.cloud import PointCloud, read_cloud, read_vis_file, vis_path
from evdense.log import get_logger, progress
from evdense.mvs.maps_io import read_colmap_array
from evdense.mvs.workspace import Workspace

log = get_logger("mvs")

FUSION_METHODS = ("voxel", "colmap")


@dataclass
class FusionConfig:
    """Settings of the fusion of depth maps into one point cloud."""

    method: str = "voxel"
    """voxel (ours - back-projection and per-voxel mean, with visibility) or colmap
    (pycolmap.stereo_fusion, CPU)."""
    voxel_size: float = 0.0
    """Voxel edge (model units, metres for GT poses); 0 = ``voxel_size_px`` times the median
    footprint of a pixel at the median depth."""
    voxel_size_px: float = 1.0
    """Automatic voxel size, in pixel footprints at the median depth."""
    min_views: int = 1
    """Voxels seen by fewer views are dropped."""
    outlier_neighbors: int = 16
    """Statistical outlier removal: neighbours considered (0 = no removal)."""
    outlier_std_ratio: float = 2.5
    """Statistical outlier removal: points whose mean neighbour distance exceeds the global mean by
    this many standard deviations are dropped."""
    batch_views: int = 16
    """Views back-projected between two merges (bounds memory on long sequences)."""
    colmap_max_reproj_error: float = 2.0
    """method=colmap: StereoFusionOptions.max_reproj_error (pixels)."""
    colmap_max_depth_error: float = 0.01
    """method=colmap: StereoFusionOptions.max_depth_error (relative)."""
    colmap_max_normal_error: float = 10.0
    """method=colmap: StereoFusionOptions.max_normal_error (degrees)."""
    colmap_min_num_pixels: int = 3
    """method=colmap: StereoFusionOptions.min_num_pixels."""

    def check(self) -> None:
        if self.method not in FUSION_METHODS:
            raise ValueError(
                f"mvs.fusion.method must be one of {FUSION_METHODS}, got {self.method!r}"
            )
        if self.voxel_size < 0 or self.voxel_size_px <= 0:
            raise ValueError("mvs.fusion.voxel_size must be >= 0 and voxel_size_px > 0")


@lru_cache(maxsize=8)
def _rays(K: tuple[float, ...], height: int, width: int) -> np.ndarray:
    """z = 1 rays ``(H * W, 3)`` of a pinhole ``K`` (flattened row-major 3x3)."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1)
    return pix @ np.linalg.inv(np.array(K).reshape(3, 3)).T


def backproject(
    depth: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World points ``(n, 3)`` of the valid pixels of a depth map ``(H, W)`` (z-depth, 0 =
    invalid) and their flat pixel indices ``(n,)``."""
    H, W = depth.shape
    flat = np.flatnonzero(depth > 0)
    rays = _rays(tuple(np.asarray(K, np.float64).ravel()), H, W)[flat]
    Xc = rays * depth.reshape(-1)[flat, None].astype(np.float64)
    return (Xc - t) @ R, flat  # R^T (Xc - t)


def auto_voxel_size(ws: Workspace, kind: str, px: float) -> float:
    """``px`` times the median over views of (median valid depth / focal length)."""
    sizes = []
    for im in ws.images:
        p = ws.map_path("depth", im.name, kind)
        if not p.is_file():
            continue
        d = read_colmap_array(p)
        if (d > 0).any():
            sizes.append(np.median(d[d > 0]) / np.sqrt(im.K[0, 0] * im.K[1, 1]))
    if not sizes:
        return 0.0
    return float(px * np.median(sizes))


_BITS = 21
_OFF = 1 << (_BITS - 1)


def _voxel_keys(X: np.ndarray, size: float) -> np.ndarray:
    k = np.floor(X / size).astype(np.int64)
    if np.abs(k).max(initial=0) >= _OFF:
        raise ValueError(
            f"voxel size {size:g} too small for a scene this large (over 2^20 voxels per axis)"
        )
    k += _OFF
    return (k[:, 0] << (2 * _BITS)) | (k[:, 1] << _BITS) | k[:, 2]


def _merge(keys: np.ndarray, vals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum the rows of ``vals`` per unique key; returns sorted unique keys and their sums."""
    uk, inv = np.unique(keys, return_inverse=True)
    out = np.empty((len(uk), vals.shape[1]), np.float64)
    for c in range(vals.shape[1]):  # bincount: much faster than np.add.at
        out[:, c] = np.bincount(inv, weights=vals[:, c], minlength=len(uk))
    return uk, out


def fuse_voxels(ws: Workspace, kind: str, cfg: FusionConfig) -> PointCloud:
    """Our fusion: back-project every view's ``kind`` maps, merge per voxel (see module docstring)."""
    size = cfg.voxel_size or auto_voxel_size(ws, kind, cfg.voxel_size_px)
    empty = PointCloud(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), [])
    if size <= 0:
        log.warning("%s: no valid depth in any %s map; empty cloud", ws.root, kind)
        return empty
    log.info("fusion: voxel size %.4g (model units)", size)
    acc_k = np.zeros(0, np.int64)
    acc_v = np.zeros((0, 10), np.float64)  # xyz, normal, rgb, count
    pend_k: list[np.ndarray] = []
    pend_v: list[np.ndarray] = []
    used: list[int] = []
    for i, im in progress(list(enumerate(ws.images)), desc="fusion", logger=log):
        dp, np_ = ws.map_path("depth", im.name, kind), ws.map_path("normal", im.name, kind)
        if not (dp.is_file() and np_.is_file()):
            continue
        depth = read_colmap_array(dp)
        X, flat = backproject(depth, im.K, im.R, im.t)
        if len(flat) == 0:
            continue
        used.append(i)
        n_cam = read_colmap_array(np_).reshape(-1, 3)[flat].astype(np.float64)
        n_w = n_cam @ im.R  # R^T n
        rgb = ws.read_rgb(im.name).reshape(-1, 3)[flat].astype(np.float64)
        keys = _voxel_keys(X, size)
        pend_k.append(keys)
        pend_v.append(np.concatenate([X, n_w, rgb, np.ones((len(X), 1))], 1))
        if len(pend_k) >= cfg.batch_views:
            acc_k, acc_v = _merge(
                np.concatenate([acc_k, *pend_k]), np.concatenate([acc_v, *pend_v])
            )
            pend_k, pend_v = [], []
    if pend_k:
        acc_k, acc_v = _merge(np.concatenate([acc_k, *pend_k]), np.concatenate([acc_v, *pend_v]))
    if len(acc_k) == 0:
        log.warning("%s: no valid depth in any %s map; empty cloud", ws.root, kind)
        return empty
    # second pass: which views saw each voxel (sorted keys -> searchsorted)
    pairs_v: list[np.ndarray] = []
    pairs_i: list[np.ndarray] = []
    for i in used:
        im = ws.images[i]
        X, _ = backproject(read_colmap_array(ws.map_path("depth", im.name, kind)), im.K, im.R, im.t)
        vox = np.unique(np.searchsorted(acc_k, _voxel_keys(X, size)))
        pairs_v.append(vox)
        pairs_i.append(np.full(len(vox), i, np.int64))
    pv, pi = np.concatenate(pairs_v), np.concatenate(pairs_i)
    order = np.argsort(pv, kind="stable")
    pv, pi = pv[order], pi[order]
    bounds = np.searchsorted(pv, np.arange(len(acc_k) + 1))
    visibility = np.split(pi, bounds[1:-1])
    count = acc_v[:, 9:10]
    pts = acc_v[:, :3] / count
    nrm = acc_v[:, 3:6]
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    col = np.clip(np.rint(acc_v[:, 6:9] / count), 0, 255).astype(np.uint8)
    cloud = PointCloud(pts, nrm, col, visibility)
    if cfg.min_views > 1:
        cloud = cloud.subset(np.array([len(v) >= cfg.min_views for v in visibility], bool))
    return cloud


def fuse_colmap(ws: Workspace, kind: str, cfg: FusionConfig, num_threads: int = -1) -> PointCloud:
    """COLMAP's fusion (``pycolmap.stereo_fusion``) of the ``kind`` maps of the workspace."""
    import pycolmap

    opts = pycolmap.StereoFusionOptions()
    opts.max_reproj_error = cfg.colmap_max_reproj_error
    opts.max_depth_error = cfg.colmap_max_depth_error
    opts.max_normal_error = cfg.colmap_max_normal_error
    opts.min_num_pixels = cfg.colmap_min_num_pixels
    opts.num_threads = num_threads
    out = ws.root / "stereo" / "colmap_fused.ply"
    pycolmap.stereo_fusion(
        output_path=str(out),
        workspace_path=str(ws.root),
        input_type=kind,
        options=opts,
        output_type="PLY",
    )
    cloud = read_cloud(out, read_vis=False, allow_empty=True)
    vp = vis_path(out)
    vis = read_vis_file(vp) if vp.is_file() else [np.zeros(0, np.int64)] * len(cloud)
    cloud.visibility = [np.asarray(v, np.int64) for v in vis]
    return cloud


def remove_outliers(cloud: PointCloud, neighbors: int, std_ratio: float) -> PointCloud:
    """open3d's statistical outlier removal; returns the kept points."""
    if neighbors <= 0 or len(cloud) <= neighbors:
        return cloud
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    _, idx = pcd.remove_statistical_outlier(nb_neighbors=int(neighbors), std_ratio=float(std_ratio))
    return cloud.subset(np.asarray(idx, np.int64))


def fuse_workspace(
    ws: Workspace, cfg: FusionConfig, kind: str = "geometric", num_threads: int = -1
) -> PointCloud:
    """Fuse the workspace's ``kind`` maps with the configured method, then remove outliers."""
    cfg.check()
    cloud = (
        fuse_voxels(ws, kind, cfg)
        if cfg.method == "voxel"
        else fuse_colmap(ws, kind, cfg, num_threads)
    )
    n0 = len(cloud)
    cloud = remove_outliers(cloud, cfg.outlier_neighbors, cfg.outlier_std_ratio)
    log.info("fusion (%s): %d points, %d after outlier removal", cfg.method, n0, len(cloud))
    return cloud
