"""Evaluation of a recording by the ground truth it carries: GT poses (ATE after Sim(3)) and APS
frames (event frames against the nearest APS frame), with no GT surface."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from evdense.evaluate.config import EvalConfig
from evdense.evaluate.images import evaluate_against_reference
from evdense.evaluate.stage import run_evaluate
from evdense.poses import look_at, write_tum


def _frames(folder: Path, images: list[np.ndarray], times: list[float]) -> Path:
    folder.mkdir(parents=True)
    for i, img in enumerate(images):
        iio.imwrite(folder / f"{i:06d}.png", img)
    (folder / "timestamps.txt").write_text("".join(f"{i} {t:.6f}\n" for i, t in enumerate(times)))
    return folder


def _texture(rng, h=60, w=80) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    return (255 * np.clip(gaussian_filter(rng.random((h + 8, w + 8)), 2) * 4 - 1.5, 0, 1)).astype(
        np.uint8
    )


def test_frames_against_nearest_aps_frame(tmp_path, rng):
    tex = [_texture(rng) for _ in range(3)]
    aps = _frames(tmp_path / "aps", [t[4:64, 4:84] for t in tex], [0.0, 0.1, 0.2])
    # event frames at 4x the APS rate; the ones nearest each APS frame show its scene, shifted by
    # 2 px and with another gain and offset; the others show noise
    imgs, times = [], []
    for k in range(9):
        t = 0.025 * k
        j = int(round(t / 0.1))
        if abs(t - 0.1 * j) < 1e-9:
            imgs.append((0.5 * tex[j][4:64, 6:86] + 60).astype(np.uint8))
        else:
            imgs.append(rng.integers(0, 255, (60, 80), dtype=np.uint8))
        times.append(t + 0.001)
    ev = _frames(tmp_path / "ev", imgs, times)
    res = evaluate_against_reference(ev, aps, EvalConfig())
    assert res["reference"] == "aps_nearest" and res["num_frames"] == 3
    assert res["ssim"] > 0.97 and res["mse"] < 1e-3
    # against the wrong frames (the noise ones) the score drops
    noise = _frames(tmp_path / "noise", [imgs[1], imgs[5], imgs[7]], [0.0, 0.1, 0.2])
    assert evaluate_against_reference(noise, aps, EvalConfig())["ssim"] < 0.3


def test_recording_without_gt_surface_scores_its_trajectory(tmp_path):
    gt, sfm = tmp_path / "gt", tmp_path / "sfm"
    gt.mkdir()
    sfm.mkdir()
    t = np.linspace(0, 1, 30)
    poses = np.stack([look_at(np.array([0.5 * s, 0.0, -2.0]), np.zeros(3)) for s in t])
    write_tum(gt / "trajectory.txt", t, poses)
    # SfM's trajectory: the same path in another frame (scale 3, shifted), at frame times only
    est = poses[::3].copy()
    est[:, :3, 3] = 3 * est[:, :3, 3] + np.array([1.0, 2.0, 3.0])
    write_tum(sfm / "trajectory.txt", t[::3], est)
    (sfm / "stats.json").write_text(json.dumps({"num_registered": 10, "num_selected": 10}))
    out = run_evaluate(gt, sfm, tmp_path / "m.json", labels={"dataset": "rec"})
    assert out["geometry"] == {} and "images" not in out
    assert out["trajectory"]["ate_rmse"] == pytest.approx(0.0, abs=1e-6)
    assert out["trajectory"]["scale"] == pytest.approx(1 / 3)
    assert json.loads((tmp_path / "m.json").read_text())["trajectory"]["num_poses"] == 10
    # the alignment is recorded, so that the figures draw the SfM cameras in the GT frame
    a = out["alignment"]
    moved = a["scale"] * est[:, :3, 3] @ np.asarray(a["R"]).T + np.asarray(a["t"])
    np.testing.assert_allclose(moved, poses[::3, :3, 3], atol=1e-6)
    # a failed SfM is recorded as failed, with no trajectory
    (sfm / "stats.json").write_text(json.dumps({"failed": True, "error": "2 of 10 registered"}))
    out = run_evaluate(gt, sfm, tmp_path / "m2.json")
    assert out["failed"] and "trajectory" not in out


def test_gt_mesh_of_a_recording_is_imported_and_checked(tmp_path, rng):
    import open3d as o3d

    from evdense.errors import InputError
    from evdense.io import ingest_recording
    from evdense.testing.recordings import write_rpg_text

    t = np.arange(100) * 100
    write_rpg_text(tmp_path / "rec", t, rng.integers(0, 32, 100), rng.integers(0, 24, 100),
                   rng.choice([-1, 1], 100))  # fmt: skip
    box = o3d.geometry.TriangleMesh.create_box(1.0, 2.0, 3.0)
    o3d.io.write_triangle_mesh(str(tmp_path / "scan.obj"), box)
    t_gt = np.linspace(0, 0.01, 5)
    write_tum(tmp_path / "poses.txt", t_gt,
              np.stack([look_at(np.array([s, 0.0, -2.0]), np.zeros(3)) for s in t_gt]))  # fmt: skip
    res = ingest_recording(tmp_path / "rec", tmp_path / "out" / "e.h5", gt_dir=tmp_path / "gt",
                           width=32, height=24, gt_mesh=tmp_path / "scan.obj",
                           gt_trajectory=tmp_path / "poses.txt")  # fmt: skip
    got = o3d.io.read_triangle_mesh(str(tmp_path / "gt" / "mesh.ply"))
    assert res.gt_mesh == str(tmp_path / "gt" / "mesh.ply") and len(got.triangles) == 12
    assert res.num_poses == 5 and (tmp_path / "gt" / "trajectory.txt").is_file()
    np.testing.assert_allclose(got.get_max_bound(), [1.0, 2.0, 3.0])
    # a point cloud is not a surface: refused, naming the file, and no event file left
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rng.random((50, 3))))
    o3d.io.write_point_cloud(str(tmp_path / "cloud.ply"), pcd)
    with pytest.raises(InputError) as e:
        ingest_recording(tmp_path / "rec", tmp_path / "out2" / "e.h5", gt_dir=tmp_path / "gt2",
                         width=32, height=24, gt_mesh=tmp_path / "cloud.ply")  # fmt: skip
    assert str(tmp_path / "cloud.ply") in str(e.value) and "no triangles" in str(e.value)
    assert not (tmp_path / "out2" / "e.h5").exists()


def test_gt_mesh_key_is_checked_in_the_config(tmp_path):
    from evdense.config import ConfigError, check_config, validate_config

    (tmp_path / "rec.txt").write_text("0 1 1 1\n")
    conf = validate_config({"datasets": {"r": {"recording": "rec.txt", "gt_mesh": "no.ply"}}})
    with pytest.raises(ConfigError, match=r"datasets\.r\.gt_mesh.*no such file"):
        check_config(conf, base_dir=tmp_path)
    conf = validate_config({"datasets": {"s": {"scene": "room", "gt_mesh": "x.ply"}}})
    with pytest.raises(ConfigError, match=r"datasets\.s\.gt_mesh.*only for a recording"):
        check_config(conf, base_dir=tmp_path)
