"""Evaluation metrics on hand-made clouds, meshes, trajectories and images."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from evdense.camera import Camera
from evdense.evaluate.align import refine_with_icp, truncated_cost
from evdense.evaluate.geometry_metrics import (
    evaluate_geometry,
    observed_surface_samples,
    sample_surface,
    surface_distance,
)
from evdense.evaluate.images import image_metrics
from evdense.evaluate.trajectory_errors import evaluate_trajectory
from evdense.poses import read_tum


def unit_square_mesh() -> o3d.geometry.TriangleMesh:
    """The square [0,1]^2 in the plane z = 0 (bounding-box diagonal sqrt(2))."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))


def test_surface_distance_is_exact():
    d = surface_distance(
        unit_square_mesh(), np.array([[0.5, 0.5, 0.3], [2.0, 0.5, 0.0], [0.2, 0.2, -0.1]])
    )
    np.testing.assert_allclose(d, [0.3, 1.0, 0.1], atol=1e-6)


def test_precision_recall_by_hand():
    gt = unit_square_mesh()
    diag = np.sqrt(2)
    # A dense grid on the left half of the square (complete there) plus 25 % of points 0.1 m off.
    g = np.stack(np.meshgrid(np.linspace(0, 0.5, 51), np.linspace(0, 1, 101)), -1).reshape(-1, 2)
    on = np.c_[g, np.zeros(len(g))]
    off = on[: len(on) // 3] + [0, 0, 0.1]
    pts = np.vstack([on, off])
    m = evaluate_geometry(pts, gt, relative_thresholds=[0.02 / diag], num_samples=100_000)
    assert m.thresholds == pytest.approx([0.02])
    assert m.precision[0] == pytest.approx(len(on) / len(pts), abs=1e-9)
    # Half the GT surface lies within 0.02 of the grid (plus a 0.02-wide strip beyond x = 0.5).
    assert m.recall[0] == pytest.approx(0.52, abs=0.01)
    p, r = m.precision[0], m.recall[0]
    assert m.fscore[0] == pytest.approx(2 * p * r / (p + r))
    assert m.accuracy_median == pytest.approx(0.0, abs=1e-6)


def test_mesh_against_itself_is_perfect():
    gt = unit_square_mesh()
    m = evaluate_geometry(gt, gt, relative_thresholds=[0.001], num_samples=20_000)
    assert m.precision[0] == 1.0 and m.recall[0] == 1.0
    assert m.chamfer < 1e-6


def test_observed_surface_is_what_the_cameras_see():
    # A unit cube, and a camera 3 m above its top face looking straight down (z down): with a
    # 40 x 40 px image and f = 40 px it sees a 1.5 m wide square at 3 m, so only the top face
    # (the sides are edge-on, the bottom hidden). A second camera just beside it makes two views.
    cube = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    cam = Camera(40, 40, 40.0, 40.0, 19.5, 19.5)
    down = np.diag([1.0, -1.0, -1.0])  # camera z along world -z
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[:, :3, :3] = down
    poses[0, :3, 3] = [0.5, 0.5, 4.0]
    poses[1, :3, 3] = [0.55, 0.5, 4.0]
    pts, frac = observed_surface_samples(cube, cam, poses, 5000, min_views=2)
    assert len(pts) == 5000
    assert pts[:, 2].min() > 1.0 - 1e-3  # all on the top face (to the ray-casting tolerance)
    assert frac == pytest.approx(1 / 6, abs=0.02)  # one face of six
    # Seen by only one of the cameras when it is moved away: nothing has two views.
    poses[1, :3, 3] = [20.0, 0.5, 4.0]
    pts, frac = observed_surface_samples(cube, cam, poses, 1000, min_views=2, max_rounds=2)
    assert len(pts) == 0 and frac == 0.0
    # Completeness on the observed part: the top face alone is a complete reconstruction of it.
    top = observed_surface_samples(cube, cam, poses[:1], 5000, min_views=1)[0]
    m_obs = evaluate_geometry(top, cube, [0.01], 20_000, gt_samples=top[::2])
    m_full = evaluate_geometry(top, cube, [0.01], 20_000)
    assert m_obs.recall[0] == 1.0
    assert m_full.recall[0] == pytest.approx(1 / 6 + 0.01, abs=0.03)


def random_trajectory(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0, 4, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.c_[np.cos(t), np.sin(t), 0.2 * t]
    T[:, :3, :3] = Rotation.from_rotvec(0.3 * np.c_[t, np.sin(t), np.cos(t)]).as_matrix()
    return t, T


def test_icp_keeps_a_correction_that_loses_a_few_far_points():
    """A box cloud 3 cm off its GT plus five stray points 5 cm under the bottom face (inliers at a
    6 cm threshold until the shift is undone, then 8 cm away): ICP must undo the shift even though
    the inlier fraction falls; a cloud already in place is left where it is."""
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    rng = np.random.default_rng(3)
    pts = sample_surface(box, 20_000, 1)
    bottom = np.c_[rng.uniform(0.2, 0.8, (5, 2)), np.full(5, -0.05)]
    H, info = refine_with_icp(np.vstack([pts + [0, 0, 0.03], bottom]), box, 0.06)
    assert info["fitness_after"] < info["fitness_before"] == 1.0  # the stray points left
    assert info["rmse_after"] < 0.3 * info["rmse_before"]
    assert info["accepted"]
    np.testing.assert_allclose(H[:3, 3], [0, 0, -0.03], atol=3e-3)
    assert info["cost_after"] == pytest.approx(
        truncated_cost(info["fitness_after"], info["rmse_after"], 0.06)
    )
    H, info = refine_with_icp(pts, box, 0.06)
    assert np.abs(H - np.eye(4)).max() < 2e-3  # in place: identity, or a correction below noise
    # On a random tenth of the cloud: the same correction.
    H, info = refine_with_icp(pts + [0, 0, 0.03], box, 0.06, max_points=2000)
    assert info["num_points"] == 2000 and info["accepted"]
    np.testing.assert_allclose(H[:3, 3], [0, 0, -0.03], atol=3e-3)


def test_sim3_copy_aligns_back_to_zero(rng):
    t, T = random_trajectory(50, rng)
    s, R = 3.7, Rotation.from_rotvec([0.4, -1.2, 2.0]).as_matrix()
    moved = T.copy()
    moved[:, :3, :3] = R @ T[:, :3, :3]
    moved[:, :3, 3] = s * T[:, :3, 3] @ R.T + [5, -2, 1]
    m = evaluate_trajectory(t, moved, t, T)
    assert m.ate_rmse < 1e-9
    assert m.rpe_trans_rmse < 1e-9 and m.rpe_rot_rmse_deg < 1e-5
    assert m.scale == pytest.approx(1 / s)


def test_ate_of_a_known_offset(rng):
    t, T = random_trajectory(40, rng)
    noisy = T.copy()
    # Alternating +-1 cm along z: the best similarity cannot absorb it, ATE = 1 cm.
    noisy[:, 2, 3] += 0.01 * np.where(np.arange(40) % 2 == 0, 1, -1)
    m = evaluate_trajectory(t, noisy, t, T, max_dt=1e-6)
    assert m.ate_rmse == pytest.approx(0.01, rel=0.05)


def test_published_estimate_aligns_to_motion_capture(anchors):
    """The real ECD VIO estimate aligned to its motion-capture GT has a centimetre-level ATE."""
    seq = anchors / "data" / "ecd_groundtruth" / "boxes_6dof"
    t_gt, T_gt = read_tum(seq / "stamped_groundtruth.txt")
    t_est, T_est = read_tum(seq / "stamped_traj_estimate.txt")
    m = evaluate_trajectory(t_est, T_est, t_gt, T_gt)
    assert m.num_poses > 1000
    assert m.trajectory_length > 10  # metres of hand-held motion
    assert 0.005 < m.ate_rmse < 0.5
    assert m.ate_rmse_relative < 0.02


def test_image_metrics_by_hand():
    gt = np.zeros((8, 8))
    pred = np.full((8, 8), 0.1)
    m = image_metrics(pred, gt)
    assert m["mse"] == pytest.approx(0.01)
    assert m["psnr"] == pytest.approx(20.0)
    assert image_metrics(gt + 0.5, gt + 0.5)["ssim"] == pytest.approx(1.0)


def test_compare_to_gt_ignores_tone_curve_but_not_structure(rng):
    from evdense.evaluate.images import compare_to_gt

    yy, xx = np.mgrid[0:64, 0:64]
    radiance = 0.05 + np.exp(np.sin(xx / 5.0) + np.cos(yy / 7.0))  # smooth, > 0
    gamma_frame = (radiance / radiance.max()) ** 0.45 * 255  # another monotonic tone curve
    assert compare_to_gt(gamma_frame, radiance)["ssim"] > 0.99
    shuffled = rng.permutation(gamma_frame.ravel()).reshape(gamma_frame.shape)  # same histogram
    assert compare_to_gt(shuffled, radiance)["ssim"] < 0.2


def test_claim_table_by_hand():
    import pandas as pd

    from evdense.evaluate.report import claim_table

    rows = []
    # scene a: speeds 1 and 32 at dynamic range 1, dynamic range 1e5 at speed 1
    for speed, dr, ev, conv, gt in (
        (1, 1, 0.9, 0.9, 0.95),
        (32, 1, 0.8, 0.0, 0.0),
        (1, 1e5, 0.85, 0.6, 0.9),
    ):
        for kind, f, n in (("events", ev, 60), ("conventional", conv, 3), ("gt", gt, 3)):
            rows.append({"dataset": f"a_s{speed}_dr{dr}", "scene": "a", "speed": float(speed),
                         "dynamic_range": float(dr), "source_kind": kind, "source": kind,
                         "dense_fscore": f, "sfm_num_selected": n})  # fmt: skip
    claims = claim_table(pd.DataFrame(rows)).set_index("condition")
    fast, hdr = claims.loc["fastest speed"], claims.loc["highest dynamic range"]
    assert fast["speed"] == 32 and fast["events"] == 0.8 and fast["conventional"] == 0.0
    # the oracle failed too: the claim holds only in the letter, and the note says why
    assert fast["claim_holds"] and "oracle reconstructed nothing from 3 frames" in fast["note"]
    assert np.isnan(fast["of_oracle"]) and fast["frames_events"] == 60
    assert hdr["dynamic_range"] == 1e5 and hdr["margin"] == pytest.approx(0.25)
    assert (
        hdr["of_oracle"] == pytest.approx(0.85 / 0.9) and hdr["claim_holds"] and hdr["note"] == ""
    )
    # a margin below 0.15 fails the claim
    df = pd.DataFrame(rows)
    df.loc[(df["dynamic_range"] == 1e5) & (df["source_kind"] == "conventional"), "dense_fscore"] = (
        0.75
    )
    assert not claim_table(df).set_index("condition").loc["highest dynamic range", "claim_holds"]
