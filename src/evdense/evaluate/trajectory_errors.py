"""Trajectory metrics: ATE and RPE after Sim(3) alignment to ground truth.

Poses are camera-to-world 4x4 matrices; timestamps in seconds. Monocular SfM has no scale, so the
estimate is aligned to the ground truth with a similarity (Umeyama on camera centres, see
:mod:`evdense.evaluate.align`) before any error is measured.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from evdense.evaluate.align import (
    apply_sim3_to_poses,
    camera_centre_errors,
    match_timestamps,
)
from evdense.poses import interpolate_poses


@dataclass
class TrajectoryMetrics:
    """ATE and RPE after Sim(3) alignment; translations in GT units (metres), angles in degrees."""

    num_poses: int
    scale: float
    """Scale of the Sim(3) that maps the estimate onto the GT."""
    ate_rmse: float
    ate_mean: float
    ate_max: float
    trajectory_length: float
    """Length of the GT path over the matched poses (metres)."""
    ate_rmse_relative: float
    """ATE RMSE divided by the trajectory length."""
    rpe_trans_rmse: float
    """RMSE of relative translation errors over ``rpe_delta`` consecutive matched poses (metres)."""
    rpe_rot_rmse_deg: float
    rpe_delta: int

    def to_dict(self) -> dict:
        return asdict(self)


def relative_pose_errors(
    T_est: np.ndarray, T_gt: np.ndarray, delta: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Translation (GT units) and rotation (degrees) errors of the motions over ``delta`` poses.

    Both trajectories ``(N, 4, 4)`` must already be in the same frame and scale.
    """
    rel_e = np.linalg.inv(T_est[:-delta]) @ T_est[delta:]
    rel_g = np.linalg.inv(T_gt[:-delta]) @ T_gt[delta:]
    diff = np.linalg.inv(rel_g) @ rel_e
    cosang = np.clip((np.trace(diff[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)
    return np.linalg.norm(diff[:, :3, 3], axis=1), np.degrees(np.arccos(cosang))


def evaluate_trajectory(
    t_est: np.ndarray,
    T_est: np.ndarray,
    t_gt: np.ndarray,
    T_gt: np.ndarray,
    max_dt: float | None = None,
    rpe_delta: int = 1,
) -> TrajectoryMetrics:
    """Align an estimated trajectory to GT (Sim(3) on camera centres) and compute ATE and RPE.

    Args:
        t_est, T_est: estimate timestamps ``(N,)`` in seconds and poses ``(N, 4, 4)`` camera-to-world.
        t_gt, T_gt: ground truth, same conventions.
        max_dt: pair each estimate with the nearest GT sample within ``max_dt`` seconds; ``None``
            interpolates the GT at the estimate's timestamps instead (estimates outside the GT
            time span are dropped).
        rpe_delta: RPE over this many consecutive matched poses.
    """
    T_est = np.asarray(T_est)
    if max_dt is None:
        valid, G = interpolate_poses(t_est, t_gt, T_gt)
        E = T_est[valid]
    else:
        i_est, i_gt = match_timestamps(t_est, t_gt, max_dt)
        E, G = T_est[i_est], np.asarray(T_gt)[i_gt]
    if len(E) < 3:
        raise ValueError(f"only {len(E)} estimated poses match the ground truth in time; need 3")
    ce = camera_centre_errors(E[:, :3, 3], G[:, :3, 3])
    aligned = apply_sim3_to_poses(ce.scale, ce.R, ce.t, E)
    d = max(1, min(rpe_delta, len(E) - 1))
    trans, rot = relative_pose_errors(aligned, G, d)
    return TrajectoryMetrics(
        num_poses=len(E),
        scale=ce.scale,
        ate_rmse=ce.rmse,
        ate_mean=ce.mean,
        ate_max=ce.max,
        trajectory_length=ce.trajectory_length,
        ate_rmse_relative=ce.rmse_rel,
        rpe_trans_rmse=float(np.sqrt(np.mean(trans**2))),
        rpe_rot_rmse_deg=float(np.sqrt(np.mean(rot**2))),
        rpe_delta=d,
    )
