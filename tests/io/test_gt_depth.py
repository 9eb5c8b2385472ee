"""A recording's GT surface from its GT depth maps: fused with the GT poses, scored like gt_mesh."""

from __future__ import annotations

import h5py
import imageio.v3 as iio
import numpy as np
import open3d as o3d
import pytest

from evdense.camera import Camera
from evdense.evaluate.geometry_metrics import sample_surface, surface_distance
from evdense.evaluate.rendering import depth_map
from evdense.formats.frames import write_timestamps
from evdense.io.gt_depth import fuse_depth_maps, read_depth_maps
from evdense.poses import look_at, write_tum

CAM = Camera(width=80, height=60, fx=60.0, fy=60.0, cx=39.5, cy=29.5)


def _scene() -> o3d.geometry.TriangleMesh:
    """Two boxes on a floor: exact geometry the depth maps are rendered from."""
    floor = o3d.geometry.TriangleMesh.create_box(3.0, 3.0, 0.05).translate([-1.5, -1.5, -0.05])
    a = o3d.geometry.TriangleMesh.create_box(0.6, 0.5, 0.7).translate([-0.7, -0.2, 0.0])
    b = o3d.geometry.TriangleMesh.create_box(0.4, 0.8, 0.4).translate([0.3, -0.4, 0.0])
    return floor + a + b


def _views(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 1.1, n)
    ang = np.linspace(-0.9, 0.9, n)
    eyes = np.stack([2.2 * np.sin(ang), -2.2 * np.cos(ang), np.full(n, 1.6)], axis=1)
    return t, np.stack([look_at(e, np.array([0.0, 0.0, 0.2])) for e in eyes])


def _depths(mesh, T) -> np.ndarray:
    d = np.stack([depth_map(mesh, CAM, T_wc) for T_wc in T]).astype(np.float32)
    return np.where(np.isfinite(d), d, 0.0)


def test_fused_depth_maps_give_the_surface_they_saw(tmp_path):
    mesh = _scene()
    t, T = _views()
    depth = _depths(mesh, T)
    with h5py.File(tmp_path / "depth.h5", "w") as f:
        f["depth"], f["t"] = depth, t
    d, tt = read_depth_maps(tmp_path / "depth.h5")
    assert np.isnan(d[depth == 0]).all() and np.array_equal(tt, t)
    fused = fuse_depth_maps(d, tt, CAM, t, T, voxel=0.02)
    pts = sample_surface(fused, 20_000)
    acc = surface_distance(mesh, pts)
    assert np.median(acc) < 0.01 and np.mean(acc < 0.03) > 0.95  # on the GT surface
    # and it covers what the cameras saw: back-projected depth pixels lie on the fused surface
    seen = []
    for dm, T_wc in zip(depth[::3], T[::3], strict=True):
        v, u = np.nonzero(dm > 0)
        rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(len(u))], 1)
        seen.append((rays * dm[v, u][:, None]) @ T_wc[:3, :3].T + T_wc[:3, 3])
    comp = surface_distance(fused, np.concatenate(seen))
    assert np.mean(comp < 0.03) > 0.9


def test_depth_png_folder_and_bad_depth_name_the_problem(tmp_path):
    mesh = _scene()
    t, T = _views(4)
    depth = _depths(mesh, T)
    folder = tmp_path / "depth"
    folder.mkdir()
    for k, dm in enumerate(depth):
        iio.imwrite(folder / f"{k:06d}.png", np.rint(dm * 1000).astype(np.uint16))
    write_timestamps(folder, range(len(t)), t)
    d, tt = read_depth_maps(folder)
    np.testing.assert_allclose(np.nan_to_num(d), depth, atol=6e-4)
    np.testing.assert_allclose(tt, t, atol=1e-6)
    with pytest.raises(ValueError, match="time span"):
        fuse_depth_maps(d, tt + 10.0, CAM, t, T)
    with pytest.raises(ValueError, match="80x60"):
        fuse_depth_maps(d[:, :30], tt, CAM, t, T)
    iio.imwrite(folder / "000001.png", np.zeros((60, 80), np.uint8))
    with pytest.raises(ValueError, match="000001.png: a depth PNG must be 16-bit"):
        read_depth_maps(folder)
    (tmp_path / "bad.h5").write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="bad.h5"):
        read_depth_maps(tmp_path / "bad.h5")


def test_ingest_turns_gt_depth_into_the_gt_mesh(tmp_path, rng):
    from evdense.io import ingest_recording
    from evdense.testing.recordings import write_rpg_text

    mesh = _scene()
    t, T = _views(6)
    with h5py.File(tmp_path / "depth.h5", "w") as f:
        f["depth"], f["t"] = _depths(mesh, T), t
    write_tum(tmp_path / "poses.txt", t, T)
    CAM.write_yaml(tmp_path / "calib.yaml")
    n = 200
    write_rpg_text(tmp_path / "rec", np.sort(rng.integers(0, 1_000_000, n)), rng.integers(0, 80, n),
                   rng.integers(0, 60, n), rng.choice([-1, 1], n))  # fmt: skip
    res = ingest_recording(tmp_path / "rec", tmp_path / "out" / "e.h5", gt_dir=tmp_path / "gt",
                           calibration=tmp_path / "calib.yaml", gt_trajectory=tmp_path / "poses.txt",
                           gt_depth=tmp_path / "depth.h5")  # fmt: skip
    assert res.gt_mesh == str(tmp_path / "gt" / "mesh.ply")
    assert res.gt_mesh_source == str(tmp_path / "depth.h5")
    got = o3d.io.read_triangle_mesh(res.gt_mesh)
    assert np.median(surface_distance(mesh, sample_surface(got, 5000))) < 0.01
    with pytest.raises(ValueError, match="gt_mesh or gt_depth"):
        ingest_recording(tmp_path / "rec", tmp_path / "o2" / "e.h5", gt_dir=tmp_path / "g2",
                         gt_mesh=tmp_path / "x.ply", gt_depth=tmp_path / "depth.h5")  # fmt: skip
