"""The dense cloud that MVS hands to meshing and evaluation: ``fused.ply`` and ``fused.ply.vis``.

The PLY has COLMAP's fused layout (binary little-endian; float ``x y z nx ny nz``, uchar
``red green blue``), so COLMAP, MeshLab and Open3D open it. The visibility file is COLMAP's too:
a uint64 point count, then per point a uint32 count and that many uint32 image indices
(positions in ``Reconstruction.reg_image_ids()`` order, the workspace's view order).

Only this module reads or writes these files; MVS writes them, meshing, evaluation and the
figures read them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evdense.formats.files import atomic_path

VIS_SUFFIX = ".vis"


def vis_path(cloud_path: str | Path) -> Path:
    """The visibility file beside a cloud: ``<cloud>.vis``."""
    return Path(str(cloud_path) + VIS_SUFFIX)


@dataclass
class PointCloud:
    """Points ``(N, 3)`` float64 in metres; unit normals ``(N, 3)`` float64 or None; colours
    ``(N, 3)`` uint8 (as the file stores them) or None; per point the indices of the views that
    saw it, or None when there is no visibility file."""

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    visibility: list[np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, keep: np.ndarray) -> PointCloud:
        """The points selected by a boolean mask or an index array (with their attributes)."""
        idx = np.nonzero(keep)[0] if keep.dtype == bool else keep
        return PointCloud(
            self.points[idx],
            None if self.normals is None else self.normals[idx],
            None if self.colors is None else self.colors[idx],
            None if self.visibility is None else [self.visibility[i] for i in idx],
        )

    def colors_float(self) -> np.ndarray | None:
        """Colours as floats in [0, 1] (what Open3D holds), or None."""
        return None if self.colors is None else self.colors.astype(np.float64) / 255.0


def write_vis_file(path: str | Path, visibility: list[np.ndarray]) -> None:
    """Write COLMAP's visibility file (see the module docstring), atomically."""
    path = Path(path)
    counts = np.array([len(v) for v in visibility], np.uint32)
    if not len(visibility):
        counts = np.zeros(0, np.uint32)
    body = np.empty(len(visibility) + int(counts.sum()), np.uint32)
    starts = np.concatenate([[0], np.cumsum(counts.astype(np.int64) + 1)[:-1]]).astype(np.int64)
    if len(visibility):
        body[starts] = counts
        mask = np.ones(len(body), bool)
        mask[starts] = False
        body[mask] = np.concatenate([np.asarray(v, np.uint32) for v in visibility])
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(np.array([len(visibility)], "<u8").tobytes())
        f.write(body.astype("<u4").tobytes())


def read_vis_file(path: str | Path) -> list[np.ndarray]:
    """Read COLMAP's visibility file; per point an int64 array of view indices.

    Raises ``ValueError`` naming the file when it is truncated.
    """
    path = Path(path)
    raw = path.read_bytes()
    if len(raw) < 8:
        raise ValueError(f"{path}: truncated visibility file")
    n = int(np.frombuffer(raw, "<u8", count=1)[0])
    data = np.frombuffer(raw, "<u4", offset=8).astype(np.int64)
    out: list[np.ndarray] = []
    pos = 0
    for _ in range(n):
        if pos >= len(data) or pos + 1 + int(data[pos]) > len(data):
            raise ValueError(f"{path}: truncated visibility file ({len(out)} of {n} points)")
        k = int(data[pos])
        out.append(data[pos + 1 : pos + 1 + k])
        pos += 1 + k
    return out


def write_cloud(path: str | Path, cloud: PointCloud, write_vis: bool = True) -> Path:
    """Write ``cloud`` as a binary PLY in COLMAP's fused layout and, with ``write_vis``, its
    visibility file (first, so that a cloud never appears without it); both atomically. Missing
    normals or colours are written as zeros."""
    path = Path(path)
    n = len(cloud)
    rec = np.zeros(
        n,
        dtype=[(k, "<f4") for k in ("x", "y", "z", "nx", "ny", "nz")]
        + [(k, "u1") for k in ("red", "green", "blue")],
    )
    normals = cloud.normals if cloud.normals is not None else np.zeros((n, 3))
    colors = cloud.colors if cloud.colors is not None else np.zeros((n, 3), np.uint8)
    for j, k in enumerate("xyz"):
        rec[k] = cloud.points[:, j]
        rec["n" + k] = normals[:, j]
    for j, k in enumerate(("red", "green", "blue")):
        rec[k] = colors[:, j]
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(rec.tobytes())
        if write_vis:
            visibility = cloud.visibility
            if visibility is None:
                visibility = [np.zeros(0, np.int64)] * n
            write_vis_file(vis_path(path), visibility)
    return path


def read_cloud(path: str | Path, read_vis: bool = True, allow_empty: bool = False) -> PointCloud:
    """Read a PLY cloud (any layout Open3D reads) and, with ``read_vis``, its visibility file
    when there is one.

    Normals that are all-zero placeholders come back as None. Raises ``ValueError`` naming the
    file when it is missing, holds no points (unless ``allow_empty``: an empty cloud is what MVS
    writes when SfM failed), holds non-finite coordinates, or when its visibility file does not
    match it.
    """
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: point cloud file not found")
    pcd = o3d.io.read_point_cloud(str(path))
    pts = np.asarray(pcd.points, dtype=np.float64)
    if len(pts) == 0 and not allow_empty:
        raise ValueError(f"{path}: no points in the cloud")
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{path}: the cloud holds non-finite coordinates")
    normals = np.asarray(pcd.normals, dtype=np.float64) if pcd.has_normals() else None
    if normals is not None and np.mean(np.linalg.norm(normals, axis=1) < 1e-6) > 0.5:
        normals = None  # a placeholder (all zeros), not normals
    colors = np.rint(np.asarray(pcd.colors) * 255.0).astype(np.uint8) if pcd.has_colors() else None
    vis = None
    vp = vis_path(path)
    if read_vis and vp.is_file():
        vis = read_vis_file(vp)
        if len(vis) != len(pts):
            raise ValueError(f"{vp}: {len(vis)} visibility entries for {len(pts)} points in {path}")
    return PointCloud(pts, normals, colors, vis)
