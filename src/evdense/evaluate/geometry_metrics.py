"""Geometry metrics of a reconstruction (points or mesh) against a ground-truth mesh.

Definitions (the usual ones of the Tanks and Temples / ETH3D benchmarks):

- accuracy: distance from each reconstructed point to the GT surface; precision(tau) is the
  fraction of reconstructed points within ``tau`` of it;
- completeness: distance from each GT surface sample to the reconstruction; recall(tau) is the
  fraction of GT samples within ``tau`` of it;
- F-score(tau) = 2 P R / (P + R); Chamfer = mean accuracy + mean completeness.

Completeness is measured on the whole GT surface, or (``gt_samples``, see
:func:`observed_surface_samples`) on the part of it that the GT cameras saw: a reconstruction
cannot be asked to recover walls the camera never looked at, and counting them would bury every
difference between image sources under the same unseen area (ETH3D and DTU likewise score
completeness only where their ground truth was observed).

Distances to the GT surface are exact point-to-triangle distances (open3d ray-casting scene);
distances to a reconstruction are to its points, or to its surface when it is a mesh.
Thresholds are absolute (metres) or relative to the GT bounding-box diagonal.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from evdense.evaluate.config import EvalConfig
from evdense.log import get_logger
from evdense.poses import read_tum

log = get_logger("evaluate")


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
    curve: dict[str, list[float]] | None = None
    """Precision, recall and F-score at many thresholds (``relative_thresholds`` beside them), for
    the threshold plot; None unless asked for."""

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


def observed_surface_samples(
    mesh: o3d.geometry.TriangleMesh,
    camera,
    poses_wc: np.ndarray,
    num_samples: int,
    min_views: int = 2,
    seed: int = 0,
    max_rounds: int = 8,
) -> tuple[np.ndarray, float]:
    """Uniform samples of the part of ``mesh`` seen by at least ``min_views`` of the cameras.

    A sample is seen by a camera (``camera``: :class:`evdense.camera.Camera`; ``poses_wc``:
    camera-to-world ``(V, 4, 4)``) when it lies in front of it, projects inside the image and the
    first surface along the ray from the camera centre is the sample itself (ray casting). Area-
    uniform candidates are drawn in rounds of ``num_samples`` until ``num_samples`` are kept or
    ``max_rounds`` rounds are spent.

    Returns the kept samples ``(M, 3)`` (``M <= num_samples``) and the fraction of the surface
    area seen (kept / drawn).
    """
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    tol = 1e-4 * bbox_diagonal(mesh)
    kept: list[np.ndarray] = []
    drawn = total = 0
    for r in range(max_rounds):
        cand = sample_surface(mesh, num_samples, seed + 1000 * r)
        seen = np.zeros(len(cand), np.int32)
        for T in poses_wc:
            c = T[:3, 3]
            pc = (cand - c) @ T[:3, :3]  # world -> camera: R^T (p - c)
            front = pc[:, 2] > 1e-6
            uv = np.full((len(cand), 2), -1.0)
            uv[front] = camera.project(pc[front])
            inside = (
                front
                & (uv[:, 0] >= -0.5)
                & (uv[:, 0] <= camera.width - 0.5)
                & (uv[:, 1] >= -0.5)
                & (uv[:, 1] <= camera.height - 0.5)
            )
            idx = np.flatnonzero(inside)
            if len(idx) == 0:
                continue
            d = cand[idx] - c
            dist = np.linalg.norm(d, axis=1)
            rays = np.hstack([np.broadcast_to(c, d.shape), d / dist[:, None]]).astype(np.float32)
            hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
            seen[idx[hit >= dist - tol - 1e-5 * dist]] += 1
        ok = cand[seen >= min_views]
        drawn += len(cand)
        total += len(ok)
        kept.append(ok)
        if total >= num_samples:
            break
    pts = np.concatenate(kept)[:num_samples] if kept else np.zeros((0, 3))
    return pts, total / max(drawn, 1)


def bbox_diagonal(mesh: o3d.geometry.TriangleMesh) -> float:
    """Length of the axis-aligned bounding-box diagonal of ``mesh`` (metres)."""
    v = np.asarray(mesh.vertices)
    return float(np.linalg.norm(v.max(0) - v.min(0)))


def geometry_distances(
    recon: np.ndarray | o3d.geometry.TriangleMesh,
    gt: o3d.geometry.TriangleMesh,
    num_samples: int = 200_000,
    crop_margin: float = 0.0,
    seed: int = 0,
    gt_samples: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The two distance sets every score is made of: accuracy (each reconstructed point, or
    sample of a reconstructed mesh, to the GT surface) and completeness (each GT sample to the
    reconstruction); see :func:`evaluate_geometry` for the arguments. Empty accuracy when the
    reconstruction is empty (completeness is then infinite)."""
    diag = bbox_diagonal(gt)
    if isinstance(recon, o3d.geometry.TriangleMesh):
        pts = sample_surface(recon, num_samples, seed) if len(recon.triangles) else np.zeros((0, 3))
    else:
        pts = np.asarray(recon, dtype=np.float64).reshape(-1, 3)
    if crop_margin > 0 and len(pts):
        v = np.asarray(gt.vertices)
        lo, hi = v.min(0) - crop_margin * diag, v.max(0) + crop_margin * diag
        pts = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    if gt_samples is None:
        gt_samples = sample_surface(gt, num_samples, seed + 1)
    elif len(gt_samples) == 0:
        raise ValueError("gt_samples is empty: no observed GT surface to measure completeness on")
    if len(pts) == 0:
        return np.zeros(0), np.full(len(gt_samples), np.inf)
    acc = surface_distance(gt, pts)
    if isinstance(recon, o3d.geometry.TriangleMesh):
        comp = surface_distance(recon, gt_samples)
    else:
        comp, _ = cKDTree(pts).query(gt_samples, workers=-1)
    return acc, comp


def scores_at(
    acc: np.ndarray, comp: np.ndarray, thresholds: list[float] | np.ndarray
) -> tuple[list[float], list[float], list[float]]:
    """Precision, recall and F-score at each absolute threshold (0 when nothing was reconstructed)."""
    if len(acc) == 0:
        zeros = [0.0] * len(thresholds)
        return zeros, list(zeros), list(zeros)
    prec = [float(np.mean(acc < t)) for t in thresholds]
    rec = [float(np.mean(comp < t)) for t in thresholds]
    f = [2 * p * r / (p + r) if p + r > 0 else 0.0 for p, r in zip(prec, rec, strict=True)]
    return prec, rec, f


def evaluate_geometry(
    recon: np.ndarray | o3d.geometry.TriangleMesh,
    gt_mesh: o3d.geometry.TriangleMesh | str | Path,
    relative_thresholds: list[float] = (0.0025, 0.005, 0.01, 0.02),
    num_samples: int = 200_000,
    crop_margin: float = 0.0,
    seed: int = 0,
    gt_samples: np.ndarray | None = None,
    curve_thresholds: list[float] | None = None,
) -> GeometryMetrics:
    """Compare a reconstruction with the GT mesh.

    Args:
        recon: reconstructed points ``(N, 3)`` or a triangle mesh (sampled with ``num_samples``).
        gt_mesh: the ground-truth mesh (or its PLY path), in the same frame as ``recon``.
        relative_thresholds: distance thresholds as fractions of the GT bounding-box diagonal.
        num_samples: GT surface samples for completeness (and samples of a reconstructed mesh).
        crop_margin: reconstructed points outside the GT bounding box grown by this fraction of
            the diagonal are dropped before scoring (0 keeps everything).
        gt_samples: the GT points completeness is measured on ``(M, 3)`` (for example
            :func:`observed_surface_samples`); default ``num_samples`` samples of the whole mesh.
        curve_thresholds: relative thresholds of an extra precision/recall/F curve
            (:attr:`GeometryMetrics.curve`; None: no curve).
    """
    gt = _as_legacy_mesh(gt_mesh)
    diag = bbox_diagonal(gt)
    taus = [r * diag for r in relative_thresholds]
    acc, comp = geometry_distances(recon, gt, num_samples, crop_margin, seed, gt_samples)
    prec, rec, f = scores_at(acc, comp, taus)
    curve = None
    if curve_thresholds is not None:
        cp, cr, cf = scores_at(acc, comp, [r * diag for r in curve_thresholds])
        curve = {
            "relative_thresholds": [float(r) for r in curve_thresholds],
            "precision": cp,
            "recall": cr,
            "fscore": cf,
        }
    if len(acc) == 0:
        inf = float("inf")
        return GeometryMetrics(
            0, inf, inf, inf, inf, inf, taus, list(relative_thresholds), prec, rec, f, curve
        )
    return GeometryMetrics(
        num_points=len(acc),
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
        curve=curve,
    )


def gt_reference_samples(
    gt_dir: Path, gt_mesh: o3d.geometry.TriangleMesh, conf: EvalConfig
) -> tuple[np.ndarray | None, dict[str, Any]]:
    """The GT points completeness is measured on, and a description of them for the metrics file.

    ``observed``: :func:`~evdense.evaluate.geometry_metrics.observed_surface_samples` from
    ``visibility_views`` GT cameras evenly spaced in time over ``gt_dir/trajectory.txt``;
    ``full``: None (the whole surface, sampled by :func:`evaluate_geometry`).
    """
    if conf.completeness_reference == "full":
        return None, {"kind": "full", "num_samples": conf.num_samples}
    from evdense.camera import load_camera
    from evdense.poses import interpolate_poses

    t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
    times = np.linspace(t_gt.min(), t_gt.max(), conf.visibility_views)
    _, poses = interpolate_poses(times, t_gt, T_gt)
    cam = load_camera(gt_dir / "intrinsics.yaml")
    pts, frac = observed_surface_samples(
        gt_mesh, cam, poses, conf.num_samples, conf.visibility_min_views, seed=1
    )
    if len(pts) == 0:
        raise ValueError(f"{gt_dir}: the GT cameras see no part of the GT mesh")
    log.info(
        "observed GT surface: %.1f%% of the mesh area (%d samples, >= %d of %d views)",
        100 * frac, len(pts), conf.visibility_min_views, conf.visibility_views,
    )  # fmt: skip
    info = {
        "kind": "observed",
        "num_samples": len(pts),
        "observed_area_fraction": frac,
        "views": conf.visibility_views,
        "min_views": conf.visibility_min_views,
    }
    return pts, info
