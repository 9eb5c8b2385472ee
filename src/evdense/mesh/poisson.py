"""Screened Poisson surface reconstruction (open3d), trimmed to where the cloud has support."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from evdense.log import get_logger
from evdense.mesh.geometry import median_spacing

log = get_logger("mesh.poisson")


@dataclass
class PoissonConfig:
    """Settings of the screened Poisson mesher."""

    depth: int = 10
    """Octree depth (the finest grid has 2**depth cells along the bounding cube)."""
    scale: float = 1.1
    """Ratio between the reconstruction cube and the cloud's bounding cube."""
    linear_fit: bool = False
    """Place iso-vertices by linear interpolation (sharper, sometimes noisier)."""
    density_quantile: float = 0.05
    """Vertices whose Poisson density (input samples supporting them) is below this quantile are dropped."""
    max_distance: float = 4.0
    """Faces whose centroid is farther than this many median point spacings from every input point
    are dropped (no invented surface where nothing was seen); 0 disables."""
    normal_neighbours: int = 30
    """Neighbours used to estimate normals when the cloud has none."""


def ensure_normals(
    pcd: o3d.geometry.PointCloud, centers: np.ndarray | None, neighbours: int = 30
) -> o3d.geometry.PointCloud:
    """Estimate normals when missing, oriented towards the mean camera centre (or consistently by
    a tangent-plane walk when no camera is given)."""
    if pcd.has_normals():
        return pcd
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(neighbours))
    if centers is not None and len(centers):
        pts = np.asarray(pcd.points)
        nrm = np.asarray(pcd.normals)
        # Towards the nearest camera: works inside rooms and around objects alike.
        _, nearest = cKDTree(centers).query(pts)
        flip = np.einsum("ij,ij->i", nrm, centers[nearest] - pts) < 0
        nrm[flip] *= -1
        pcd.normals = o3d.utility.Vector3dVector(nrm)
    else:
        pcd.orient_normals_consistent_tangent_plane(neighbours)
    return pcd


def poisson_mesh(
    points: np.ndarray,
    normals: np.ndarray | None,
    config: PoissonConfig | None = None,
    colors: np.ndarray | None = None,
    centers: np.ndarray | None = None,
) -> o3d.geometry.TriangleMesh:
    """Screened Poisson mesh of ``points (N, 3)`` with oriented ``normals (N, 3)`` (estimated when
    None, oriented towards ``centers``), trimmed by density and by distance to the cloud."""
    config = config or PoissonConfig()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(np.asarray(normals, dtype=np.float64))
    if colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(np.clip(np.asarray(colors, dtype=np.float64), 0, 1))
    ensure_normals(pcd, centers, config.normal_neighbours)
    mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        pcd, depth=config.depth, scale=config.scale, linear_fit=config.linear_fit
    )
    dens = np.asarray(dens)
    n0 = len(mesh.triangles)
    if config.density_quantile > 0 and len(dens):
        mesh.remove_vertices_by_mask(dens < np.quantile(dens, config.density_quantile))
    if config.max_distance > 0 and len(mesh.triangles):
        pts = np.asarray(pcd.points)
        spacing = median_spacing(pts)
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
        d, _ = cKDTree(pts).query(v[f].mean(axis=1), workers=-1)
        mesh.remove_triangles_by_mask(d > config.max_distance * spacing)
        mesh.remove_unreferenced_vertices()
    log.info("Poisson mesh: %d faces, %d kept after trimming", n0, len(mesh.triangles))
    if len(mesh.triangles) == 0:
        raise ValueError("Poisson mesher: no face left after trimming")
    return mesh
