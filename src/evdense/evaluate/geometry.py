"""Geometry metrics of a reconstruction (points or mesh) against a ground-truth mesh.

Definitions (the usual ones of the Tanks and Temples / ETH3D benchmarks):

- accuracy: distance from each reconstructed point to the GT surface; precision(tau) is the
  fraction of reconstructed points within ``tau`` of it;
- completeness: distance from each GT surface sample to the reconstruction; recall(tau) is the
  fraction of GT samples within ``tau`` of it;
- F-score(tau) = 2 P R / (P + R); Chamfer = mean accuracy + mean completeness.

Distances to the GT surface are exact point-to-triangle distances (open3d ray-casting scene);
distances to a reconstruction are to its points, or to its surface when it is a mesh.
Thresholds are absolute (metres) or relative to the GT bounding-box diagonal.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree


@dataclass
class GeometryMetrics:
    """Accuracy, completeness and F-scores of one reconstruction; distances in metres."""

    num_points: int
    """Reconstructed points (or surface samples of a reconstructed mesh) evaluated."""
    accuracy_mean: float
    accuracy_median: float
    completeness_mean: float
    completeness_median: float
    chamfer: float
    thresholds: list[float] = field(default_factory=list)
    """Absolute thresholds (metres), in the order of the lists below."""
    relative_thresholds: list[float] = field(default_factory=list)
    """The same thresholds as fractions of the GT bounding-box diagonal."""
    precision: list[float] = field(default_factory=list)
    recall: list[float] = field(default_factory=list)
    fscore: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


def _as_legacy_mesh(mesh: o3d.geometry.TriangleMesh | str | Path) -> o3d.geometry.TriangleMesh:
    if isinstance(mesh, str | Path):
        m = o3d.io.read_triangle_mesh(str(mesh))
        if len(m.triangles) == 0:
            raise ValueError(f"{mesh}: no triangles in mesh file")
        return m
    return mesh


def surface_distance(mesh: o3d.geometry.TriangleMesh, points: np.ndarray) -> np.ndarray:
    """Unsigned distance from ``points (N, 3)`` to the surface of ``mesh`` (metres), ``(N,)``."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    q = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
    return scene.compute_distance(q).numpy().astype(np.float64)


def sample_surface(mesh: o3d.geometry.TriangleMesh, num_points: int, seed: int = 0) -> np.ndarray:
    """Uniform samples ``(num_points, 3)`` on the surface of ``mesh`` (area-weighted, seeded)."""
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.triangles)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(f), size=num_points, p=area / area.sum())
    r1, r2 = rng.random(num_points), rng.random(num_points)
    s = np.sqrt(r1)
    w0, w1, w2 = 1 - s, s * (1 - r2), s * r2
    return w0[:, None] * a[tri] + w1[:, None] * b[tri] + w2[:, None] * c[tri]


def bbox_diagonal(mesh: o3d.geometry.TriangleMesh) -> float:
    """Length of the axis-aligned bounding-box diagonal of ``mesh`` (metres)."""
    v = np.asarray(mesh.vertices)
    return float(np.linalg.norm(v.max(0) - v.min(0)))


def evaluate_geometry(
    recon: np.ndarray | o3d.geometry.TriangleMesh,
    gt_mesh: o3d.geometry.TriangleMesh | str | Path,
    relative_thresholds: list[float] = (0.0025, 0.005, 0.01, 0.02),
    num_samples: int = 200_000,
    crop_margin: float = 0.0,
    seed: int = 0,
) -> GeometryMetrics:
    """Compare a reconstruction with the GT mesh.

    Args:
        recon: reconstructed points ``(N, 3)`` or a triangle mesh (sampled with ``num_samples``).
        gt_mesh: the ground-truth mesh (or its PLY path), in the same frame as ``recon``.
        relative_thresholds: distance thresholds as fractions of the GT bounding-box diagonal.
        num_samples: GT surface samples for completeness (and samples of a reconstructed mesh).
        crop_margin: reconstructed points outside the GT bounding box grown by this fraction of
            the diagonal are dropped before scoring (0 keeps everything).
    """
    gt = _as_legacy_mesh(gt_mesh)
    diag = bbox_diagonal(gt)
    if isinstance(recon, o3d.geometry.TriangleMesh):
        pts = sample_surface(recon, num_samples, seed) if len(recon.triangles) else np.zeros((0, 3))
    else:
        pts = np.asarray(recon, dtype=np.float64).reshape(-1, 3)
    if crop_margin > 0 and len(pts):
        v = np.asarray(gt.vertices)
        lo, hi = v.min(0) - crop_margin * diag, v.max(0) + crop_margin * diag
        pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    taus = [r * diag for r in relative_thresholds]
    gt_samples = sample_surface(gt, num_samples, seed + 1)
    if len(pts) == 0:
        inf = float("inf")
        return GeometryMetrics(
            0,
            inf,
            inf,
            inf,
            inf,
            inf,
            taus,
            list(relative_thresholds),
            [0.0] * len(taus),
            [0.0] * len(taus),
            [0.0] * len(taus),
        )
    acc = surface_distance(gt, pts)
    if isinstance(recon, o3d.geometry.TriangleMesh):
        comp = surface_distance(recon, gt_samples)
    else:
        comp, _ = cKDTree(pts).query(gt_samples, workers=-1)
    prec = [float(np.mean(acc < t)) for t in taus]
    rec = [float(np.mean(comp < t)) for t in taus]
    f = [2 * p * r / (p + r) if p + r > 0 else 0.0 for p, r in zip(prec, rec, strict=True)]
    return GeometryMetrics(
        num_points=len(pts),
        accuracy_mean=float(acc.mean()),
        accuracy_median=float(np.median(acc)),
        completeness_mean=float(comp.mean()),
        completeness_median=float(np.median(comp)),
        chamfer=float(acc.mean() + comp.mean()),
        thresholds=taus,
        relative_thresholds=list(relative_thresholds),
        precision=prec,
        recall=rec,
        fscore=f,
    )
