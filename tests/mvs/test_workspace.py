"""MVS files and workspace: COLMAP depth/normal .bin maps (read back by pycolmap's fusion),
visibility and PLY files, source-view selection, the ground-truth (oracle) model and its evaluation."""

from __future__ import annotations

import numpy as np
import pytest

from evdense.camera import Camera
from evdense.mvs.maps_io import read_colmap_array, write_colmap_array
from evdense.testing.mvs_scenes import Plane, plane_scene

W, H = 96, 72
CAM = Camera(W, H, 80.0, 80.0, 47.5, 35.5)
PLANE = Plane(point=np.array([0.0, 0.0, 2.0]), normal=np.array([0.3, 0.0, -1.0]), texel=0.04)
CENTERS = [np.array(c, float) for c in ((0, 0, 0), (-0.4, 0, 0), (0.4, 0.05, 0), (0, 0.3, 0))]


def test_colmap_array_layout_and_round_trip(tmp_path):
    a = np.arange(4 * 3 * 2, dtype=np.float32).reshape(4, 3, 2)  # (H, W, C)
    write_colmap_array(tmp_path / "a.bin", a)
    raw = (tmp_path / "a.bin").read_bytes()
    assert raw.startswith(b"3&4&2&")
    data = np.frombuffer(raw[len(b"3&4&2&") :], "<f4")
    # COLMAP's Mat: data[c * W * H + row * W + col]
    for row, col, c in ((0, 0, 0), (1, 2, 0), (3, 1, 1), (2, 0, 1)):
        assert data[c * 3 * 4 + row * 3 + col] == a[row, col, c]
    np.testing.assert_array_equal(read_colmap_array(tmp_path / "a.bin"), a)
    d = np.random.default_rng(0).random((5, 7)).astype(np.float32)
    write_colmap_array(tmp_path / "d.bin", d)
    np.testing.assert_array_equal(read_colmap_array(tmp_path / "d.bin"), d)
    assert not list(tmp_path.glob("*.partial"))


def test_bad_colmap_arrays_raise_naming_the_file(tmp_path):
    (tmp_path / "junk.bin").write_bytes(b"hello world")
    with pytest.raises(ValueError, match="junk.bin"):
        read_colmap_array(tmp_path / "junk.bin")
    write_colmap_array(tmp_path / "t.bin", np.ones((4, 4), np.float32))
    (tmp_path / "t.bin").write_bytes((tmp_path / "t.bin").read_bytes()[:-4])
    with pytest.raises(ValueError, match="t.bin"):
        read_colmap_array(tmp_path / "t.bin")


def _plane_workspace(tmp_path):
    """Frames, GT depths and a known COLMAP model of four views of a plane, undistorted into a
    dense workspace."""
    import imageio.v3 as iio

    from evdense.mvs.oracle import sample_tracks, write_known_model
    from evdense.mvs.workspace import undistort_to_workspace

    views, depths, poses = plane_scene(PLANE, CENTERS, np.array([0, 0, 2.0]), CAM.K, W, H)
    frames = tmp_path / "frames"
    frames.mkdir()
    names = [f"{i:06d}.png" for i in range(len(views))]
    for n, v in zip(names, views, strict=True):
        iio.imwrite(frames / n, (v.image * 255).round().astype(np.uint8))
    P, tracks = sample_tracks(np.stack(depths), CAM, np.stack(poses), 12, 0.01)
    write_known_model(tmp_path / "sparse", CAM, names, np.stack(poses), P, tracks)
    ws = undistort_to_workspace(tmp_path / "sparse", frames, tmp_path / "ws")
    return ws, depths, poses


def test_workspace_cameras_sources_and_ranges(tmp_path):
    from evdense.mvs.workspace import ViewSelectionConfig, depth_range, select_source_views

    ws, depths, poses = _plane_workspace(tmp_path)
    assert [im.name for im in ws.images] == [f"{i:06d}.png" for i in range(4)]
    # intrinsics back in evdense's convention, poses as given
    np.testing.assert_allclose(ws.images[0].K, CAM.K, atol=1e-9)
    np.testing.assert_allclose(ws.images[2].center, CENTERS[2], atol=1e-9)
    v = ws.stereo_view("000001.png")
    assert v.image.shape == (H, W) and 0 <= v.image.min() and v.image.max() <= 1
    cfg = ViewSelectionConfig(num_source_views=2, min_shared_points=3, optimal_angle=30.0)
    src = select_source_views(ws, cfg)
    assert all(len(s) == 2 and i not in s for i, s in enumerate(src))
    # views 1 and 2 are 0.8 m apart (the widest angle, ~23 deg, below the optimal 30 deg):
    # each is the other's best source
    assert src[1][0] == 2 and src[2][0] == 1
    # a minimum angle above every pair's removes all sources
    assert select_source_views(ws, ViewSelectionConfig(min_angle=40.0)) == [[], [], [], []]
    lo, hi = depth_range(
        ws, 0, ViewSelectionConfig(depth_margin=0.0, depth_percentiles=(0.0, 100.0))
    )
    gt = depths[0][depths[0] > 0]
    assert gt.min() * 0.97 <= lo and hi <= gt.max() * 1.03


def test_colmap_fusion_reads_our_maps(tmp_path):
    """Exact depth and normal maps written by us, fused by pycolmap.stereo_fusion: the points lie
    on the plane (within COLMAP's half-pixel back-projection shift) with the right normals."""
    from evdense.mvs.fusion import FusionConfig, fuse_colmap
    from evdense.mvs.workspace import write_patch_match_cfg

    ws, depths, poses = _plane_workspace(tmp_path)
    n_world = PLANE.normal / np.linalg.norm(PLANE.normal)
    for im, d, T in zip(ws.images, depths, poses, strict=True):
        n_cam = np.broadcast_to(T[:3, :3].T @ n_world, (H, W, 3))
        for what, arr in (("depth", d), ("normal", n_cam), ("cost", np.zeros_like(d))):
            p = ws.map_path(what, im.name, "geometric")
            p.parent.mkdir(parents=True, exist_ok=True)
            write_colmap_array(p, arr)
    write_patch_match_cfg(ws, [[1, 2], [0, 2], [0, 1], [0, 1]])
    cloud = fuse_colmap(ws, "geometric", FusionConfig(method="colmap"), num_threads=1)
    assert len(cloud) > 1000
    dist = np.abs((cloud.points - PLANE.point) @ n_world)
    assert np.median(dist) < 0.02  # half a pixel at 2 m is 1.25 cm
    assert np.median(cloud.normals @ n_world) > 0.99
    assert all(len(v) >= 1 for v in cloud.visibility[:100])


def test_own_fusion_of_exact_maps(tmp_path):
    from evdense.mvs.fusion import FusionConfig, fuse_workspace

    ws, depths, poses = _plane_workspace(tmp_path)
    n_world = PLANE.normal / np.linalg.norm(PLANE.normal)
    for im, d, T in zip(ws.images, depths, poses, strict=True):
        n_cam = np.broadcast_to(T[:3, :3].T @ n_world, (H, W, 3))
        for what, arr in (("depth", d), ("normal", n_cam), ("cost", np.zeros_like(d))):
            p = ws.map_path(what, im.name, "geometric")
            p.parent.mkdir(parents=True, exist_ok=True)
            write_colmap_array(p, arr)
    cloud = fuse_workspace(ws, FusionConfig(voxel_size=0.05, outlier_neighbors=0), "geometric")
    dist = np.abs((cloud.points - PLANE.point) @ n_world)
    assert dist.max() < 0.05  # a voxel averages points of one plane: on it, up to the voxel
    assert np.median(dist) < 2e-3
    assert (cloud.normals @ n_world > 0.999).all()
    # voxels are unique, and four views see most of them
    keys = np.floor(cloud.points / 0.05)
    assert len(np.unique(keys, axis=0)) >= 0.9 * len(keys)
    assert np.median([len(v) for v in cloud.visibility]) >= 3


def test_config_from_dict_rejects_unknown_keys():
    from evdense.mvs.stage import MVSConfig

    cfg = MVSConfig.from_dict(
        {"patch_match": {"iterations": [2, 1]}, "view_selection": {"depth_percentiles": [2, 98]}}
    )
    assert cfg.patch_match.iterations == [2, 1] and cfg.view_selection.depth_percentiles == (2, 98)
    with pytest.raises(ValueError, match="mvs.patch_match: unknown keys \\['iters'\\]"):
        MVSConfig.from_dict({"patch_match": {"iters": 3}})
    with pytest.raises(ValueError, match="mvs.fusion.method"):
        MVSConfig.from_dict({"fusion": {"method": "poisson"}})


def _write_gt_folder(gt, n=8):
    """A ground-truth folder as the simulator writes it, for a textured plane."""
    import h5py
    import imageio.v3 as iio
    import open3d as o3d

    from evdense.poses import look_at, write_tum

    gt.mkdir(parents=True)
    (gt / "frames").mkdir()
    CAM.write_yaml(gt / "intrinsics.yaml")
    times = np.arange(n) / 10.0
    centers = [np.array([x, 0.1 * np.sin(3 * x), 0.0]) for x in np.linspace(-0.4, 0.4, n)]
    target = np.array([0.0, 0.0, 2.0])
    plane = Plane(point=target, normal=np.array([0.0, 0.0, -1.0]), texel=0.04)
    views, depths, poses = plane_scene(plane, centers, target, CAM.K, W, H)
    # trajectory at twice the frame rate: interpolation must land on the frame poses
    t_dense = np.arange(2 * n - 1) / 20.0
    dense = []
    for t in t_dense:
        k = int(t * 10)
        if np.isclose(t * 10, k):
            dense.append(poses[k])
        else:
            c = (centers[k] + centers[k + 1]) / 2
            dense.append(look_at(c, target, up=(0.0, -1.0, 0.0)))
    write_tum(gt / "trajectory.txt", t_dense, np.stack(dense))
    for i, v in enumerate(views):
        iio.imwrite(gt / "frames" / f"{i:06d}.png", (v.image * 255).round().astype(np.uint8))
    (gt / "frames" / "timestamps.txt").write_text(
        "".join(f"{i} {t:.9f}\n" for i, t in enumerate(times))
    )
    with h5py.File(gt / "depth.h5", "w") as f:
        f.create_dataset("depth", data=np.stack(depths))
        f.create_dataset("t", data=times)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.array([[-3, -3, 2], [3, -3, 2], [3, 3, 2], [-3, 3, 2.0]])),
        o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]])),
    )
    o3d.io.write_triangle_mesh(str(gt / "mesh.ply"), mesh)
    return poses


def test_oracle_model_from_ground_truth(tmp_path):
    from evdense.mvs.oracle import OracleConfig, build_gt_model
    from evdense.mvs.workspace import read_workspace

    poses = _write_gt_folder(tmp_path / "gt")
    build_gt_model(
        tmp_path / "gt",
        tmp_path / "oracle" / "sparse",
        OracleConfig(max_frames=5, point_grid_step=12),
    )
    ws = read_workspace(tmp_path / "oracle")  # the model folder is <root>/sparse
    assert [im.name for im in ws.images] == [f"{i:06d}.png" for i in (0, 2, 4, 5, 7)]
    np.testing.assert_allclose(ws.images[1].center, poses[2][:3, 3], atol=1e-9)
    np.testing.assert_allclose(ws.images[0].K, CAM.K, atol=1e-9)
    assert len(ws.points) > 100
    np.testing.assert_allclose(ws.points[:, 2], 2.0, atol=1e-4)  # samples of the plane z = 2
    assert np.mean([len(o) for o in ws.observed]) > 20


def test_oracle_check_end_to_end(tmp_path):
    """GT model -> run_mvs -> evaluation: high precision and recall on a plane."""
    from evdense.mvs.oracle import OracleConfig, build_gt_model, evaluate_mvs
    from evdense.mvs.stage import run_mvs

    _write_gt_folder(tmp_path / "gt")
    sparse = build_gt_model(
        tmp_path / "gt", tmp_path / "oracle" / "sparse" / "0", OracleConfig(point_grid_step=12)
    )
    conf = {
        "patch_match": {"iterations": [3, 2, 1]},
        "view_selection": {"num_source_views": 3, "min_shared_points": 3},
    }
    run_mvs(sparse, tmp_path / "gt" / "frames", tmp_path / "mvs", conf, threads=1)
    res = evaluate_mvs(tmp_path / "mvs", tmp_path / "gt", threshold=0.005)
    assert res["precision"] > 0.9
    assert (
        res["recall"] > 0.5
    )  # the frames see more of the plane than the fused, filtered maps keep
    assert res["depth_median_rel_error"] < 0.01
    assert len(res["maps"]) == 8


def test_missing_frame_raises_before_any_map(tmp_path):
    import imageio.v3 as iio

    from evdense.mvs.oracle import sample_tracks, write_known_model
    from evdense.mvs.workspace import undistort_to_workspace

    views, depths, poses = plane_scene(PLANE, CENTERS[:3], np.array([0, 0, 2.0]), CAM.K, W, H)
    frames = tmp_path / "frames"
    frames.mkdir()
    names = [f"{i:06d}.png" for i in range(3)]
    for n, v in zip(names[:2], views[:2], strict=True):  # the third frame is missing
        iio.imwrite(frames / n, (v.image * 255).round().astype(np.uint8))
    P, tracks = sample_tracks(np.stack(depths), CAM, np.stack(poses), 12, 0.01)
    write_known_model(tmp_path / "sparse", CAM, names, np.stack(poses), P, tracks)
    with pytest.raises(ValueError, match="000002.png"):
        undistort_to_workspace(tmp_path / "sparse", frames, tmp_path / "ws")
    assert not (tmp_path / "ws" / "sparse").exists()


def test_a_workspace_made_from_other_inputs_is_not_resumed(tmp_path):
    from evdense.mvs.stage import MVSConfig
    from evdense.mvs.workspace import discard_stale_workspace, input_fingerprint

    sparse, images, out = tmp_path / "sparse", tmp_path / "frames", tmp_path / "mvs"
    sparse.mkdir()
    images.mkdir()
    (sparse / "images.bin").write_bytes(b"model A")
    (images / "000000.png").write_bytes(b"frame A")
    fp_a = input_fingerprint(sparse, images, MVSConfig())
    assert not discard_stale_workspace(out, fp_a)  # empty: nothing to discard
    (out / "stereo").mkdir()
    (out / "stereo" / "map.bin").write_bytes(b"depth of A")
    assert not discard_stale_workspace(out, fp_a)  # same inputs: resumed, maps kept
    assert (out / "stereo" / "map.bin").is_file()
    (images / "000000.png").write_bytes(b"frame B")  # the frames were reconstructed anew
    fp_b = input_fingerprint(sparse, images, MVSConfig())
    assert fp_b != fp_a
    assert discard_stale_workspace(out, fp_b)
    assert not (out / "stereo").exists()
