"""The pictures of a run: distance colouring, alignment of cameras, sweeps and the claim figure."""

from __future__ import annotations

import json

import numpy as np
import open3d as o3d
import pandas as pd

from evdense.camera import Camera
from evdense.evaluate.align import apply_sim3_to_poses
from evdense.evaluate.dataset_figures import SourceFiles, distance_view, load_source
from evdense.evaluate.report import make_figures
from evdense.poses import look_at, write_tum


def _plane(z: float, half: float = 1.0) -> o3d.geometry.TriangleMesh:
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]]))
    )


def test_distance_view_colours_a_shifted_plane_by_its_offset():
    cam = Camera(width=64, height=48, fx=40.0, fy=40.0, cx=31.5, cy=23.5)
    T_wc = look_at(np.array([0.0, 0.0, 2.0]), np.zeros(3), up=(0.0, 1.0, 0.0))
    recon, gt = _plane(0.05, half=0.5), _plane(0.0, half=1.0)
    dist, shade = distance_view(recon, gt, cam, T_wc)
    seen = np.isfinite(dist)
    assert 0.1 < seen.mean() < 0.9  # the small plane fills part of the view, the rest is NaN
    assert np.allclose(dist[seen], 0.05, atol=1e-5)
    assert np.allclose(shade[seen], 1.0, atol=0.2)  # seen head-on
    back, _ = distance_view(gt, recon, cam, T_wc)  # GT points beyond the small plane are farther
    assert np.isfinite(back).mean() > seen.mean()
    assert np.nanmin(back) >= 0.05 - 1e-5 and np.nanmax(back) > 0.1


def test_the_evaluations_alignment_puts_sfm_cameras_on_the_gt_path(tmp_path):
    t = np.linspace(0, 1, 12)
    eyes = np.stack([np.cos(t), np.sin(t), 0.3 * t + 1], axis=1)
    T_gt = np.stack([look_at(e, np.zeros(3)) for e in eyes])
    ang = 0.7
    R = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    s, tr = 2.5, np.array([0.3, -1.0, 0.2])
    # the SfM frame: GT moved by the inverse similarity
    T_sfm = apply_sim3_to_poses(1 / s, R.T, -R.T @ tr / s, T_gt)
    sfm = tmp_path / "sfm"
    sfm.mkdir()
    write_tum(sfm / "trajectory.txt", t, T_sfm)
    (sfm / "stats.json").write_text("{}")
    metrics = tmp_path / "metrics.json"
    icp = np.eye(4)
    icp[:3, 3] = [0.01, 0, 0]  # the geometry's ICP step, not the trajectory's
    metrics.write_text(
        json.dumps(
            {"alignment": {"scale": s, "R": R.tolist(), "t": tr.tolist(), "icp": icp.tolist()}}
        )
    )
    loaded = load_source("ours", SourceFiles(sfm=sfm, metrics=metrics))
    assert not loaded.failed
    assert np.allclose(loaded.T_cam[:, :3, 3], eyes, atol=1e-6)
    assert np.allclose(loaded.T_cam[:, :3, :3], T_gt[:, :3, :3], atol=1e-6)
    # points are drawn after the ICP as well: the same similarity, then the 1 cm shift
    p = np.array([0.2, 0.1, 0.4])
    moved = loaded.transform[:3, :3] @ p + loaded.transform[:3, 3]
    assert np.allclose(moved, s * R @ p + tr + [0.01, 0, 0])


def test_run_figures_follow_what_the_run_sweeps(tmp_path):
    rows = []
    for scene in ("room", "desk"):
        for speed in (1.0, 4.0):
            for source, kind in (("ours_n25000_b5", "events"), ("conventional", "conventional"),
                                 ("gt", "gt")):  # fmt: skip
                f = {"events": 0.6, "conventional": 0.9 - 0.1 * speed, "gt": 0.95}[kind]
                rows.append(
                    {
                        "dataset": f"{scene}_{speed}",
                        "scene": scene,
                        "speed": speed,
                        "dynamic_range": 1.0,
                        "source": source,
                        "source_kind": kind,
                        "method": "ours" if kind == "events" else None,
                        "window": "n25000" if kind == "events" else None,
                        "bins": 5 if kind == "events" else None,
                        "refined_fscore": f,
                        "ate_rmse_relative": 0.01,
                    }  # fmt: skip
                )
    made = make_figures(pd.DataFrame(rows), tmp_path)
    names = {p.name for p in made}
    assert {"refined_fscore_vs_speed.png", "ate_rmse_relative_vs_speed.png"} <= names
    assert {"refined_fscore_vs_speed.pdf", "claim.png"} <= names
    assert not any("window_events" in n or "_vs_bins" in n for n in names)  # not swept here

    sweep = []
    for n in (10_000, 25_000, 50_000):
        sweep.append({"dataset": "room_1", "scene": "room", "speed": 1.0, "dynamic_range": 1.0,
                      "source": f"ours_n{n}_b5", "source_kind": "events", "method": "ours",
                      "window": f"n{n}", "bins": 5, "refined_fscore": 0.5 + n / 1e5})  # fmt: skip
    sweep.append({"dataset": "room_1", "scene": "room", "speed": 1.0, "dynamic_range": 1.0,
                  "source": "gt", "source_kind": "gt", "refined_fscore": 0.9})  # fmt: skip
    made = make_figures(pd.DataFrame(sweep), tmp_path / "sweep")
    assert {p.name for p in made} == {"refined_fscore_vs_window_events.png",
                                      "refined_fscore_vs_window_events.pdf"}  # fmt: skip
