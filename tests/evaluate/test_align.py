"""Sim(3) alignment (Umeyama), timestamp pairing and camera-centre errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evdense.evaluate.align import (
    align_trajectory_to_gt,
    apply_sim3,
    apply_sim3_to_poses,
    camera_centre_errors,
    match_timestamps,
    trajectory_length,
    umeyama_sim3,
)
from evdense.poses import interpolate_poses, look_at


def _random_sim3(rng):
    return (
        2.7,
        Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(),
        rng.normal(size=3) * 5,
    )


def test_umeyama_recovers_sim3_exactly(rng):
    src = rng.normal(size=(50, 3))
    s, R, t = _random_sim3(rng)
    dst = apply_sim3(s, R, t, src)
    s2, R2, t2 = umeyama_sim3(src, dst)
    assert s2 == pytest.approx(s, rel=1e-12)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-11)
    assert np.linalg.det(R2) == pytest.approx(1.0)


def test_umeyama_without_scale_is_rigid(rng):
    src = rng.normal(size=(20, 3))
    _, R, t = _random_sim3(rng)
    dst = apply_sim3(1.0, R, t, src)
    s2, R2, t2 = umeyama_sim3(src, dst, with_scale=False)
    assert s2 == 1.0
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-11)
    # a scaled copy cannot be matched rigidly: residual stays
    s3, _, _ = umeyama_sim3(src, 2 * dst, with_scale=False)
    assert s3 == 1.0


def test_umeyama_never_returns_a_reflection(rng):
    src = rng.normal(size=(30, 3))
    dst = src * np.array([1, 1, -1])  # a mirror image: best proper rotation, det +1
    _, R, _ = umeyama_sim3(src, dst)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_umeyama_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 3"):
        umeyama_sim3(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        umeyama_sim3(np.zeros((5, 3)), np.zeros((4, 3)))


def test_camera_centre_errors_of_a_noisy_copy(rng):
    gt = np.cumsum(rng.normal(size=(40, 3)) * 0.1, axis=0)
    s, R, t = _random_sim3(rng)
    est = apply_sim3(1 / s, R.T, np.zeros(3), gt - t)  # estimate in another frame and scale
    noise = rng.normal(size=est.shape) * 1e-3
    ce = camera_centre_errors(est + noise, gt)
    assert ce.scale == pytest.approx(s, rel=1e-2)
    assert ce.rmse < 5e-3 * s  # noise of 1e-3 estimate units, times the scale
    assert ce.trajectory_length == pytest.approx(trajectory_length(gt))
    assert ce.summary()["rmse_rel_trajectory"] == pytest.approx(ce.rmse / ce.trajectory_length)


def test_apply_sim3_to_poses_keeps_rotations_orthonormal(rng):
    s, R, t = _random_sim3(rng)
    T = np.stack([look_at(rng.normal(size=3), rng.normal(size=3) + 5) for _ in range(4)])
    T2 = apply_sim3_to_poses(s, R, t, T)
    for Ti in T2:
        np.testing.assert_allclose(Ti[:3, :3] @ Ti[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(T2[:, :3, 3], apply_sim3(s, R, t, T[:, :3, 3]))


def test_match_timestamps_nearest_within_tolerance():
    t_ref = np.array([0.3, 0.0, 0.1, 0.2])  # unsorted on purpose
    iq, ir = match_timestamps(np.array([0.01, 0.149, 0.26, 0.9]), t_ref, max_dt=0.05)
    assert iq.tolist() == [0, 1, 2]
    assert t_ref[ir].tolist() == [0.0, 0.1, 0.3]


def test_interpolate_poses_midpoint():
    T0, T1 = look_at([0, 0, 0], [0, 1, 0]), look_at([2, 0, 0], [3, 1, 0])
    valid, T = interpolate_poses(
        np.array([-1.0, 0.5, 2.0]), np.array([0.0, 1.0]), np.stack([T0, T1])
    )
    assert valid.tolist() == [False, True, False]
    np.testing.assert_allclose(T[0, :3, 3], [1, 0, 0])
    # half-way rotation: 22.5 degrees from each end
    ang = np.degrees(np.arccos((np.trace(T0[:3, :3].T @ T[0, :3, :3]) - 1) / 2))
    assert ang == pytest.approx(22.5, abs=1e-6)


def test_align_trajectory_to_gt_recovers_a_transformed_copy(rng):
    t = np.linspace(0, 2, 30)
    eyes = np.stack([np.cos(t), np.sin(t), 0.1 * t], axis=1)
    T_gt = np.stack([look_at(e, [0, 0, 0]) for e in eyes])
    s, R, tr = _random_sim3(rng)
    T_est = apply_sim3_to_poses(s, R, tr, T_gt)
    ce = align_trajectory_to_gt(t, T_est, t, T_gt)
    assert ce.scale == pytest.approx(1 / s, rel=1e-9)
    assert ce.max < 1e-9
    with pytest.raises(ValueError, match="time span"):
        align_trajectory_to_gt(t + 10, T_est, t, T_gt)
