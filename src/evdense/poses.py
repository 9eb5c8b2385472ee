"""Rigid poses, quaternions and the TUM trajectory format.

A pose is a 4x4 camera-to-world matrix ``T_wc`` (maps camera-frame points to world points).
Quaternions are ``(qx, qy, qz, qw)`` as in the TUM format.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build a 4x4 pose from a 3x3 rotation and a 3-vector translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose (or a stack ``(N, 4, 4)``)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    Ti[..., 3, 3] = 1
    return Ti


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world pose of a camera at ``eye`` looking at ``target`` (x right, y down, z forward)."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any perpendicular
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.stack([x, y, z], axis=1), eye)


def poses_to_tum(T_wc: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` poses to ``(N, 7)`` rows ``tx ty tz qx qy qz qw``."""
    q = Rotation.from_matrix(T_wc[:, :3, :3]).as_quat()  # (x, y, z, w)
    return np.concatenate([T_wc[:, :3, 3], q], axis=1)


def tum_to_poses(rows: np.ndarray) -> np.ndarray:
    """``(N, 7)`` rows ``tx ty tz qx qy qz qw`` to ``(N, 4, 4)`` poses."""
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(rows[:, 3:7]).as_matrix()
    T[:, :3, 3] = rows[:, :3]
    return T


def write_tum(path: str | Path, t: np.ndarray, T_wc: np.ndarray) -> None:
    """Write a TUM trajectory: ``t tx ty tz qx qy qz qw`` per line, ``t`` in seconds."""
    rows = np.concatenate([np.asarray(t, dtype=np.float64)[:, None], poses_to_tum(T_wc)], axis=1)
    np.savetxt(path, rows, fmt="%.9f", header="timestamp tx ty tz qx qy qz qw")


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory; returns timestamps ``(N,)`` in seconds and poses ``(N, 4, 4)``.

    Raises ``ValueError`` naming the file and line when a row does not have 8 numbers.
    """
    path = Path(path)
    rows = []
    for i, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise ValueError(
                f"{path}:{i}: expected 8 numbers 't tx ty tz qx qy qz qw', found {len(parts)}"
            )
        rows.append([float(v) for v in parts])
    if not rows:
        raise ValueError(f"{path}: no poses")
    a = np.asarray(rows)
    return a[:, 0], tum_to_poses(a[:, 1:])


def interpolate_poses(
    t_query: np.ndarray, t_ref: np.ndarray, T_ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Poses at ``t_query`` (seconds) by linear / slerp interpolation of ``T_ref``.

    Returns ``(valid, T)``: a boolean mask ``(M,)`` of queries inside ``[t_ref.min(), t_ref.max()]``
    and the interpolated poses ``(valid.sum(), 4, 4)`` (clip the queries to the span first for a
    pose at every query).
    """
    t_query = np.asarray(t_query, dtype=np.float64)
    order = np.argsort(t_ref)
    tr, Tr = np.asarray(t_ref, dtype=np.float64)[order], np.asarray(T_ref)[order]
    valid = (t_query >= tr[0]) & (t_query <= tr[-1])
    tq = t_query[valid]
    T = np.tile(np.eye(4), (len(tq), 1, 1))
    if len(tr) == 1:
        T[:] = Tr[0]
        return valid, T
    T[:, :3, :3] = Slerp(tr, Rotation.from_matrix(Tr[:, :3, :3]))(tq).as_matrix()
    for k in range(3):
        T[:, k, 3] = np.interp(tq, tr, Tr[:, k, 3])
    return valid, T
