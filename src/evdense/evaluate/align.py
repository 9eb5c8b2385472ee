"""Similarity (Sim(3)) alignment of trajectories and the camera-centre error after alignment.

An estimated trajectory (SfM, up to an unknown scale and frame) is compared with ground truth by
pairing poses by timestamp, solving for the similarity ``dst ~ s R src + t`` in closed form
(Umeyama 1991, least squares over point pairs) and measuring the residual camera-centre distances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evdense.poses import interpolate_poses


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
