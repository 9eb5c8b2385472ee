"""Ground truth written beside a simulated dataset (evdense.sim.groundtruth)."""

from __future__ import annotations

import h5py
import imageio.v3 as iio
import numpy as np
import open3d as o3d
import pytest

from evdense.camera import load_camera
from evdense.poses import read_tum
from evdense.sim.groundtruth import (
    frame_timestamps,
    gt_frame_times,
    render_gt_intensity,
    tonemap_log,
    write_groundtruth,
)
from evdense.sim.scene import load_scene

CAM = {"width": 64, "height": 48, "fx": 46.0, "fy": 46.0, "cx": 31.5, "cy": 23.5}
N = 10
SIM = {
    "render": {"camera": CAM, "gt_min_frames": N},  # the conventional camera takes exactly N
    "conventional_camera": {"fps": 10.0, "exposure_s": 0.01},
}
FRAME_T = np.arange(N) / 10.0 + 0.005
DATASET = {"scene": "room", "duration": 0.5, "speed": 0.5, "dynamic_range": 100.0, "seed": 3}


@pytest.fixture(scope="module")
def gt_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "gt"
    write_groundtruth(DATASET, SIM, out)
    return out


def test_layout_and_timestamps(gt_dir):
    names = {p.name for p in gt_dir.iterdir()}
    assert names == {
        "mesh.ply",
        "trajectory.txt",
        "intrinsics.yaml",
        "cameras.txt",
        "frames",
        "intensity.h5",
        "depth.h5",
        "scene.json",
    }
    assert not gt_dir.with_name("gt.partial").exists()
    # 1.0 s of recording (0.5 s path at half speed) at 10 Hz with 10 ms exposures: frames at the
    # middle of the exposures 0.005, 0.105, ..., 0.905 s, as the conventional camera stamps them
    lines = (gt_dir / "frames" / "timestamps.txt").read_text().splitlines()
    assert len(lines) == N
    idx, ts = zip(*(ln.split() for ln in lines), strict=True)
    assert [int(i) for i in idx] == list(range(N))
    np.testing.assert_allclose([float(t) for t in ts], FRAME_T)
    pngs = sorted((gt_dir / "frames").glob("*.png"))
    assert [p.name for p in pngs] == [f"{i:06d}.png" for i in range(N)]
    img = iio.imread(pngs[3])
    assert img.dtype == np.uint8 and img.shape == (48, 64) and img.std() > 10
    # intrinsics in both formats read back as the configured camera
    for name in ("intrinsics.yaml", "cameras.txt"):
        cam = load_camera(gt_dir / name)
        assert (cam.width, cam.height, cam.fx, cam.cx) == (64, 48, 46.0, 31.5)
    # dense TUM trajectory: 200 Hz over 1 s
    t, T = read_tum(gt_dir / "trajectory.txt")
    assert len(t) == 201 and t[-1] == pytest.approx(1.0)
    with h5py.File(gt_dir / "intensity.h5") as f:
        assert f["intensity"].shape == (N, 48, 64) and f["intensity"].dtype == np.float32
        np.testing.assert_allclose(f["t"][:], FRAME_T)
        assert f["intensity"][:].min() > 0
    with h5py.File(gt_dir / "depth.h5") as f:
        assert f["depth"].shape == (N, 48, 64) and f["depth"].dtype == np.float32


def test_depth_backprojects_onto_the_mesh(gt_dir):
    """GT consistency: depth + pose + intrinsics land on the GT mesh."""
    mesh = o3d.t.geometry.TriangleMesh.from_legacy(
        o3d.io.read_triangle_mesh(str(gt_dir / "mesh.ply"))
    )
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(mesh)
    cam = load_camera(gt_dir / "intrinsics.yaml")
    t_pose, T_pose = read_tum(gt_dir / "trajectory.txt")
    frame_t = np.loadtxt(gt_dir / "frames" / "timestamps.txt")[:, 1]
    with h5py.File(gt_dir / "depth.h5") as f:
        depth = f["depth"][:]
    rays = cam.pixel_rays().reshape(-1, 3)
    for k in (0, 4, N - 1):
        j = int(np.argmin(np.abs(t_pose - frame_t[k])))
        assert t_pose[j] == pytest.approx(frame_t[k], abs=1e-6)  # 200 Hz grid holds the frame times
        d = depth[k].reshape(-1)
        assert (d > 0).all()
        pts_c = rays * d[:, None]
        pts_w = pts_c @ T_pose[j][:3, :3].T + T_pose[j][:3, 3]
        dist = rc.compute_distance(o3d.core.Tensor(pts_w.astype(np.float32))).numpy()
        assert dist.max() < 1e-4, (
            f"frame {k}: back-projected depth is {dist.max():.4f} m off the mesh"
        )


def test_render_gt_intensity_at_any_time(gt_dir):
    with h5py.File(gt_dir / "intensity.h5") as f:
        stored = f["intensity"][[2, 7]]
    again = render_gt_intensity(gt_dir, FRAME_T[[2, 7]])
    np.testing.assert_allclose(again, stored, rtol=1e-6)
    # in between frames: a different, valid image; same from the Scene itself
    mid = render_gt_intensity(gt_dir, np.array([0.25]))
    assert mid.shape == (1, 48, 64) and mid.min() > 0 and not np.allclose(mid[0], stored[0])
    scene = load_scene(DATASET, SIM)
    np.testing.assert_allclose(render_gt_intensity(scene, [0.25]), mid, rtol=1e-6)


@pytest.mark.parametrize(
    ("dataset", "sim", "key"),
    [
        ({"scene": "hall"}, SIM, "scene"),
        ({"scene": "room", "duration": 0.0}, SIM, "duration"),
        (
            {
                "scene": {
                    "base": "room",
                    "trajectory": {"key_poses": [{"position": [0, 0, 1], "look_at": [0, 1, 1]}]},
                }
            },
            SIM,
            "key_poses",
        ),
        (
            {"scene": {"base": "room", "materials": {"wall": {"texture": "missing.png"}}}},
            SIM,
            "texture.path",
        ),
        ({"scene": "room"}, {"render": {"camera": CAM}, "conventional_camera": {"fps": 0}}, "fps"),
        ({"scene": "room"}, {"render": {"camera": CAM, "supersample": 0}}, "supersample"),
        ({"scene": "room"}, {"render": {"camera": CAM, "gt_min_frames": -1}}, "gt_min_frames"),
    ],
)
def test_invalid_config_writes_nothing(tmp_path, dataset, sim, key):
    out = tmp_path / "ds" / "gt"
    with pytest.raises(ValueError, match=key):
        write_groundtruth(dataset, sim, out)
    assert not (tmp_path / "ds").exists() or not any((tmp_path / "ds").iterdir())


def test_frame_timestamps_and_tonemap():
    np.testing.assert_allclose(frame_timestamps(0.3, 20.0), [0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3])
    img = tonemap_log(np.array([1e-3, 1e-1, 10.0, 1e4], np.float32), 1e-2, 1e3)
    assert img.tolist() == [0, 51, 153, 255]


def test_gt_frames_never_fewer_than_the_minimum():
    # enough conventional frames: GT pairs with them one to one
    t, fps = gt_frame_times(1.0, SIM, N)
    np.testing.assert_allclose(t, FRAME_T)
    assert fps == 10.0
    # fast motion, the camera takes 10 frames but the oracle is owed 21: evenly spaced over 0..1 s
    t, fps = gt_frame_times(1.0, SIM, 21)
    np.testing.assert_allclose(t, np.arange(21) / 20.0)
    assert fps == pytest.approx(20.0)
    # 0 keeps the conventional times whatever their number
    np.testing.assert_allclose(gt_frame_times(1.0, SIM, 0)[0], FRAME_T)
