"""A recording's ground-truth surface from its GT depth maps (dataset key ``gt_depth``).

Datasets such as MVSEC ship depth maps rather than a scanned model. Fused with the GT poses and
the calibration into one surface (a truncated signed distance volume over the surface's bounding
box, Open3D's ``UniformTSDFVolume``, then marching cubes), they give ``gt/mesh.ply``, and every image source of the recording
is then scored by the accuracy, completeness, P/R/F and Chamfer of synthetic scenes.

Depth maps are read from

- an HDF5 file with ``depth`` ``(N, H, W)`` float (z-depth along the optical axis, metres; 0 or
  NaN where there is no surface) and ``t`` ``(N,)`` seconds in the recording's clock (the layout
  of our simulator's ``gt/depth.h5``), or
- a frames folder (``000000.png ...`` + ``timestamps.txt``) of 16-bit PNGs in millimetres (0 = no
  surface).

The maps are taken as seen by the calibration's pinhole (rectified: its distortion is ignored).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evdense.camera import Camera
from evdense.log import get_logger
from evdense.poses import interpolate_poses

log = get_logger("gt_depth")

MAX_RESOLUTION = 384
"""Voxels along the longest side of the volume at most (384^3 voxels: about 450 MB); a finer
``voxel`` is coarsened to fit."""


def read_depth_maps(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Depth maps ``(N, H, W)`` float32 in metres (NaN where there is no surface) and their times
    ``(N,)`` in seconds. Raises ``ValueError`` naming the file when it is neither layout."""
    path = Path(path)
    if path.is_dir():
        import imageio.v3 as iio

        from evdense.formats.frames import frame_paths_and_times

        paths, t = frame_paths_and_times(path)
        maps = []
        for p in paths:
            d = iio.imread(p)
            if d.dtype != np.uint16 or d.ndim != 2:
                raise ValueError(
                    f"{p}: a depth PNG must be 16-bit grey (millimetres), not {d.dtype} {d.shape}"
                )
            maps.append(d.astype(np.float32) / 1000.0)
        depth = np.stack(maps)
    elif path.is_file():
        import h5py

        try:
            with h5py.File(path, "r") as f:
                if "depth" not in f or "t" not in f:
                    raise ValueError(f"{path}: expected datasets 'depth' (N, H, W) and 't' (N,)")
                depth, t = np.asarray(f["depth"], np.float32), np.asarray(f["t"], np.float64)
        except OSError as e:
            raise ValueError(f"{path}: not an HDF5 file of depth maps ({e})") from None
    else:
        raise FileNotFoundError(f"{path}: GT depth not found")
    if depth.ndim != 3 or len(depth) != len(t) or len(t) == 0:
        raise ValueError(f"{path}: {depth.shape} depth maps for {len(t)} times")
    depth = np.where(depth > 0, depth, np.nan).astype(np.float32)
    return depth, t


def fuse_depth_maps(
    depth: np.ndarray,
    times: np.ndarray,
    camera: Camera,
    t_gt: np.ndarray,
    T_gt: np.ndarray,
    voxel: float | None = None,
    max_depth: float | None = None,
):
    """One triangle mesh (Open3D) from depth maps seen by ``camera`` at the GT poses interpolated
    at ``times``; maps outside the GT time span are skipped. ``voxel``: TSDF voxel size in metres
    (default: the footprint of two pixels at the median depth; coarsened so that the volume has
    at most :data:`MAX_RESOLUTION` voxels a side); ``max_depth``: depths beyond it are ignored
    (default: all).

    Raises ``ValueError`` when no map falls inside the GT poses' time span or nothing is fused.
    """
    import open3d as o3d

    if depth.shape[1:] != (camera.height, camera.width):
        raise ValueError(
            f"depth maps are {depth.shape[2]}x{depth.shape[1]}, the camera {camera.width}x{camera.height}"
        )
    valid, poses = interpolate_poses(times, t_gt, T_gt)
    if not valid.any():
        raise ValueError(
            f"no depth map inside the GT poses' time span [{t_gt.min():.3f}, {t_gt.max():.3f}] s"
        )
    maps = depth[valid]
    med = float(np.nanmedian(maps)) if np.isfinite(maps).any() else float("nan")
    if not np.isfinite(med):
        raise ValueError("the depth maps hold no surface")
    if voxel is None:
        voxel = 2.0 * med / max(camera.fx, camera.fy)
    # the volume spans the back-projected surface (a uniform grid: Open3D's sparse grids put
    # this surface one voxel off in our tests), at most MAX_RESOLUTION voxels a side
    intr = o3d.camera.PinholeCameraIntrinsic(
        camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy
    )
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for d, T_wc in zip(maps, poses, strict=True):
        v, u = np.nonzero(np.isfinite(d))
        if len(u):
            rays = np.stack(
                [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(len(u))], 1
            )
            p = (rays * d[v, u][:, None]) @ T_wc[:3, :3].T + T_wc[:3, 3]
            lo, hi = np.minimum(lo, p.min(0)), np.maximum(hi, p.max(0))
    length = float((hi - lo).max()) + 8.0 * voxel
    resolution = int(min(MAX_RESOLUTION, np.ceil(length / voxel)))
    voxel = length / resolution
    trunc = 4.0 * voxel
    volume = o3d.pipelines.integration.UniformTSDFVolume(
        length=length,
        resolution=resolution,
        sdf_trunc=trunc,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.NoColor,
        origin=(lo - 4.0 * voxel).reshape(3, 1),
    )
    far = float(max_depth) if max_depth else float(np.nanmax(maps)) + trunc
    for d, T_wc in zip(maps, poses, strict=True):
        dm = np.nan_to_num(d, nan=0.0).astype(np.float32)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.zeros((*dm.shape, 3), np.uint8)),  # unused: NoColor
            o3d.geometry.Image(dm), depth_scale=1.0, depth_trunc=far, convert_rgb_to_intensity=False,
        )  # fmt: skip
        volume.integrate(rgbd, intr, np.linalg.inv(T_wc))
    mesh = volume.extract_triangle_mesh()
    if len(mesh.triangles) == 0:
        raise ValueError("fusing the GT depth maps gave no surface")
    log.info(
        "GT surface from %d depth maps: %d triangles (voxel %.4f m)",
        int(valid.sum()), len(mesh.triangles), voxel,
    )  # fmt: skip
    return mesh
