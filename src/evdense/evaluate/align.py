"""Similarity (Sim(3)) alignment of trajectories and the camera-centre error after alignment; the
scaled ICP that refines it on a GT surface, and the record of both in a metrics file.

An estimated trajectory (SfM, up to an unknown scale and frame) is compared with ground truth by
pairing poses by timestamp, solving for the similarity ``dst ~ s R src + t`` in closed form
(Umeyama 1991, least squares over point pairs) and measuring the residual camera-centre distances.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from evdense.poses import interpolate_poses

if TYPE_CHECKING:
    import open3d as o3d


def umeyama_sim3(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = True
) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity mapping ``src`` onto ``dst``: ``dst_i ~ s R src_i + t``.

    ``src`` and ``dst`` are ``(N, 3)`` corresponding points (N >= 3, not all collinear for a unique
    rotation). Returns scale ``s`` (1 when ``with_scale`` is False), rotation ``R`` ``(3, 3)`` with
    det +1, and translation ``t`` ``(3,)`` in the units of ``dst``.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(
            f"umeyama_sim3: expected two (N, 3) arrays, got {src.shape} and {dst.shape}"
        )
    if len(src) < 3:
        raise ValueError(f"umeyama_sim3: need at least 3 point pairs, got {len(src)}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs**2).sum() / len(src)
    if var_s <= 0:
        raise ValueError("umeyama_sim3: source points are all identical")
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:  # reflection: flip the weakest axis
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def apply_sim3(s: float, R: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``x -> s R x + t`` to points ``(N, 3)``; returns ``(N, 3)``."""
    return s * np.asarray(points, dtype=np.float64) @ np.asarray(R).T + np.asarray(t)


def apply_sim3_to_poses(s: float, R: np.ndarray, t: np.ndarray, T_wc: np.ndarray) -> np.ndarray:
    """Move camera-to-world poses ``(N, 4, 4)`` by the similarity; rotations stay orthonormal."""
    out = np.array(T_wc, dtype=np.float64, copy=True)
    out[:, :3, :3] = np.asarray(R) @ out[:, :3, :3]
    out[:, :3, 3] = apply_sim3(s, R, t, out[:, :3, 3])
    return out


def match_timestamps(
    t_query: np.ndarray, t_ref: np.ndarray, max_dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pair each query time with the nearest reference time within ``max_dt`` seconds.

    Returns index arrays ``(iq, ir)`` of equal length (queries without a partner are dropped).
    ``t_ref`` need not be sorted.
    """
    t_query = np.asarray(t_query, dtype=np.float64)
    t_ref = np.asarray(t_ref, dtype=np.float64)
    if len(t_ref) == 0 or len(t_query) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.argsort(t_ref)
    ts = t_ref[order]
    pos = np.clip(np.searchsorted(ts, t_query), 1, max(len(ts) - 1, 1))
    left = np.clip(pos - 1, 0, len(ts) - 1)
    right = np.clip(pos, 0, len(ts) - 1)
    pick = np.where(np.abs(ts[left] - t_query) <= np.abs(ts[right] - t_query), left, right)
    ok = np.abs(ts[pick] - t_query) <= max_dt
    return np.nonzero(ok)[0], order[pick[ok]]


def trajectory_length(positions: np.ndarray) -> float:
    """Length of the polyline through positions ``(N, 3)``, in their units."""
    p = np.asarray(positions, dtype=np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


@dataclass
class CentreErrors:
    """Camera-centre errors after similarity alignment of an estimate onto ground truth."""

    scale: float
    """Scale ``s`` of the similarity (ground-truth units per estimate unit)."""
    R: np.ndarray
    """Rotation ``(3, 3)`` of the similarity."""
    t: np.ndarray
    """Translation ``(3,)`` of the similarity, ground-truth units."""
    errors: np.ndarray
    """Per-pose camera-centre distance after alignment ``(N,)``, ground-truth units (metres)."""
    trajectory_length: float
    """Length of the ground-truth path through the paired poses, metres."""

    @property
    def rmse(self) -> float:
        return float(np.sqrt(np.mean(self.errors**2)))

    @property
    def mean(self) -> float:
        return float(np.mean(self.errors))

    @property
    def max(self) -> float:
        return float(np.max(self.errors))

    @property
    def rmse_rel(self) -> float:
        """RMSE as a fraction of the trajectory length (0.01 = 1 %)."""
        return self.rmse / self.trajectory_length if self.trajectory_length > 0 else float("nan")

    def summary(self) -> dict[str, float]:
        return {
            "num_poses": int(len(self.errors)),
            "scale": self.scale,
            "rmse_m": self.rmse,
            "mean_m": self.mean,
            "max_m": self.max,
            "trajectory_length_m": self.trajectory_length,
            "rmse_rel_trajectory": self.rmse_rel,
        }


def camera_centre_errors(est: np.ndarray, gt: np.ndarray, with_scale: bool = True) -> CentreErrors:
    """Align estimated camera centres ``(N, 3)`` onto ground-truth ones ``(N, 3)`` (paired rows)
    with :func:`umeyama_sim3` and return the residual distances (ground-truth units)."""
    s, R, t = umeyama_sim3(est, gt, with_scale=with_scale)
    err = np.linalg.norm(apply_sim3(s, R, t, est) - np.asarray(gt, dtype=np.float64), axis=1)
    return CentreErrors(scale=s, R=R, t=t, errors=err, trajectory_length=trajectory_length(gt))


def align_trajectory_to_gt(
    t_est: np.ndarray,
    T_est: np.ndarray,
    t_gt: np.ndarray,
    T_gt: np.ndarray,
    with_scale: bool = True,
) -> CentreErrors:
    """Camera-centre errors of an estimated trajectory against ground truth, paired by time.

    ``t_*`` are timestamps in seconds, ``T_*`` camera-to-world poses ``(N, 4, 4)``. Ground truth is
    interpolated at the estimate's timestamps (estimates outside the ground-truth time span are
    dropped). Raises ``ValueError`` when fewer than 3 poses can be paired.
    """
    valid, T_gt_i = interpolate_poses(t_est, t_gt, T_gt)
    if valid.sum() < 3:
        raise ValueError(
            f"only {int(valid.sum())} of {len(t_est)} estimated poses fall inside the ground-truth time span "
            f"[{np.min(t_gt):.6f}, {np.max(t_gt):.6f}] s; need at least 3 to align"
        )
    return camera_centre_errors(
        np.asarray(T_est)[valid, :3, 3], T_gt_i[:, :3, 3], with_scale=with_scale
    )


def truncated_cost(fitness: float, inlier_rmse: float, max_distance: float) -> float:
    """Mean of ``min(d, max_distance)^2`` over the points of a registration whose inliers (a
    ``fitness`` fraction, within ``max_distance``) have RMSE ``inlier_rmse``: one number that
    weighs points lost to the threshold against inliers brought closer."""
    return fitness * inlier_rmse**2 + (1.0 - fitness) * max_distance**2


def refine_with_icp(
    points: np.ndarray,
    gt_mesh: o3d.geometry.TriangleMesh,
    max_distance: float,
    seed: int = 0,
    max_points: int = 0,
) -> tuple[np.ndarray, dict[str, float]]:
    """Scaled point-to-point ICP of ``points (N, 3)`` (already roughly aligned) onto GT surface samples.

    Returns the 4x4 similarity to apply after the first alignment, and the fitness / RMSE before
    and after. ICP is accepted when it lowers the truncated cost (:func:`truncated_cost`), the
    identity is returned otherwise: a correction that brings 99.99 % of the cloud 10 % closer is
    kept even when a handful of far points leave the threshold. With ``max_points`` > 0, ICP and
    both scores use a random subset of that many points (seeded).
    """
    import open3d as o3d

    from evdense.evaluate.geometry_metrics import sample_surface

    if 0 < max_points < len(points):
        rng = np.random.default_rng(seed)
        points = points[np.sort(rng.choice(len(points), max_points, replace=False))]
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    dst = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(sample_surface(gt_mesh, 200_000, seed))
    )
    reg = o3d.pipelines.registration
    before = reg.evaluate_registration(src, dst, max_distance)
    est = reg.TransformationEstimationPointToPoint(with_scaling=True)
    crit = reg.ICPConvergenceCriteria(max_iteration=50)
    H = np.asarray(
        reg.registration_icp(src, dst, max_distance, np.eye(4), est, crit).transformation
    )
    after = reg.evaluate_registration(src, dst, max_distance, H)
    cost_before = truncated_cost(before.fitness, before.inlier_rmse, max_distance)
    cost_after = truncated_cost(after.fitness, after.inlier_rmse, max_distance)
    info = {
        "num_points": len(points),
        "fitness_before": float(before.fitness),
        "rmse_before": float(before.inlier_rmse),
        "fitness_after": float(after.fitness),
        "rmse_after": float(after.inlier_rmse),
        "cost_before": float(cost_before),
        "cost_after": float(cost_after),
        "accepted": bool(cost_after < cost_before),
    }
    return (H if info["accepted"] else np.eye(4)), info


def apply_h(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ H[:3, :3].T + H[:3, 3]


def alignment_record(
    s: float, R: np.ndarray, t: np.ndarray, icp: np.ndarray | None = None
) -> dict[str, Any]:
    """How the SfM frame was mapped onto GT: the Sim(3) from camera centres (``x -> s R x + t``)
    and the ICP refinement applied after it (4x4; identity without a GT surface)."""
    return {
        "scale": s,
        "R": np.asarray(R).tolist(),
        "t": np.asarray(t).tolist(),
        "icp": (np.eye(4) if icp is None else np.asarray(icp)).tolist(),
    }
