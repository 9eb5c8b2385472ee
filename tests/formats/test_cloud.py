"""fused.ply and fused.ply.vis: one reader and one writer, in COLMAP's layout."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from evdense.formats.cloud import (
    PointCloud,
    read_cloud,
    read_vis_file,
    vis_path,
    write_cloud,
    write_vis_file,
)


def _cloud(n: int = 50) -> PointCloud:
    rng = np.random.default_rng(1)
    nrm = rng.normal(size=(n, 3))
    return PointCloud(
        rng.random((n, 3)),
        nrm / np.linalg.norm(nrm, axis=1, keepdims=True),
        rng.integers(0, 256, (n, 3)).astype(np.uint8),
        [np.arange(i % 3) for i in range(n)],
    )


def test_vis_file_round_trip(tmp_path):
    vis = [np.array([0, 3]), np.array([], np.int64), np.array([7])]
    write_vis_file(tmp_path / "f.vis", vis)
    assert [v.tolist() for v in read_vis_file(tmp_path / "f.vis")] == [[0, 3], [], [7]]
    # COLMAP's layout: uint64 count, then per point a uint32 count and the indices
    raw = (tmp_path / "f.vis").read_bytes()
    assert raw == np.array([3], "<u8").tobytes() + np.array([2, 0, 3, 0, 1, 7], "<u4").tobytes()
    write_vis_file(tmp_path / "e.vis", [])
    assert read_vis_file(tmp_path / "e.vis") == []
    (tmp_path / "t.vis").write_bytes(raw[:-4])
    with pytest.raises(ValueError, match="t.vis: truncated"):
        read_vis_file(tmp_path / "t.vis")


def test_cloud_round_trip_in_colmaps_layout(tmp_path):
    cloud = _cloud()
    path = write_cloud(tmp_path / "fused.ply", cloud)
    raw = path.read_bytes()
    header = raw[: raw.index(b"end_header\n") + len(b"end_header\n")].decode()
    assert "element vertex 50" in header and "property uchar red" in header
    assert len(raw) - len(header) == 50 * (6 * 4 + 3)  # float x y z nx ny nz, uchar r g b
    back = read_cloud(path)
    np.testing.assert_allclose(back.points, cloud.points, atol=1e-6)
    np.testing.assert_allclose(back.normals, cloud.normals, atol=1e-6)
    np.testing.assert_array_equal(back.colors, cloud.colors)  # uint8, as stored
    np.testing.assert_allclose(back.colors_float(), cloud.colors / 255.0)
    assert [v.tolist() for v in back.visibility] == [v.tolist() for v in cloud.visibility]
    # what other tools see: Open3D reads the same points and colours
    pcd = o3d.io.read_point_cloud(str(path))
    np.testing.assert_allclose(np.asarray(pcd.colors), cloud.colors / 255.0)
    # a subset keeps each point's attributes
    sub = back.subset(np.array([3, 1]))
    assert sub.visibility[0].tolist() == cloud.visibility[3].tolist()
    np.testing.assert_array_equal(sub.colors, cloud.colors[[3, 1]])


def test_cloud_without_normals_colours_or_visibility(tmp_path):
    pts = np.random.default_rng(2).random((20, 3))
    path = write_cloud(tmp_path / "bare.ply", PointCloud(pts))
    back = read_cloud(path)
    assert back.normals is None  # zeros in the file are a placeholder, not normals
    np.testing.assert_array_equal(back.colors, np.zeros((20, 3), np.uint8))
    assert all(len(v) == 0 for v in back.visibility)
    assert read_cloud(path, read_vis=False).visibility is None


def test_bad_clouds_name_the_file(tmp_path):
    with pytest.raises(ValueError, match="missing.ply: point cloud file not found"):
        read_cloud(tmp_path / "missing.ply")
    empty = write_cloud(tmp_path / "empty.ply", PointCloud(np.zeros((0, 3))))
    with pytest.raises(ValueError, match="empty.ply: no points"):
        read_cloud(empty)
    assert len(read_cloud(empty, allow_empty=True)) == 0  # what MVS writes when SfM failed
    bad = _cloud(5)
    bad.points[2, 1] = np.nan
    with pytest.raises(ValueError, match="nan.ply: the cloud holds non-finite"):
        read_cloud(write_cloud(tmp_path / "nan.ply", bad))
    ok = write_cloud(tmp_path / "ok.ply", _cloud(5))
    write_vis_file(vis_path(ok), [np.array([1])] * 4)
    with pytest.raises(ValueError, match="ok.ply.vis: 4 visibility entries for 5 points"):
        read_cloud(ok)
