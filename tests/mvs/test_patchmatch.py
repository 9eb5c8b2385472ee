"""PatchMatch stereo on exact synthetic geometry: textured planes seen by a few pinhole cameras."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import torch

from evdense.camera import Camera
from evdense.mvs.patchmatch import (
    FilterConfig,
    PatchMatchConfig,
    estimate_depth_map,
    filter_depth_map,
)
from evdense.poses import look_at
from evdense.testing.mvs_scenes import Plane, plane_scene

W, H = 96, 72
CAM = Camera(W, H, 80.0, 80.0, 47.5, 35.5)
FAST = PatchMatchConfig(iterations=[3, 2, 1])


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _plane(slant_deg: float) -> Plane:
    s = np.radians(slant_deg)
    return Plane(
        point=np.array([0.0, 0.0, 2.0]), normal=np.array([np.sin(s), 0.0, -np.cos(s)]), texel=0.04
    )


CENTERS3 = [np.array([0.0, 0.0, 0.0]), np.array([-0.4, 0.0, 0.0]), np.array([0.4, 0.05, 0.0])]


def _range(depth: np.ndarray) -> tuple[float, float]:
    """The depth range a sparse model would give: the true range widened by 25 %."""
    return 0.75 * float(depth[depth > 0].min()), 1.25 * float(depth.max())


def _errors(dm, depth_gt, normal_gt_cam):
    m = (dm.depth > 0) & (dm.cost < 0.5) & (depth_gt > 0)
    rel = np.abs(dm.depth[m] - depth_gt[m]) / depth_gt[m]
    ang = np.degrees(np.arccos(np.clip(dm.normal[m] @ normal_gt_cam, -1, 1)))
    return m, rel, ang


@pytest.mark.parametrize("slant", [0.0, 45.0])
def test_plane_depth_and_normal_recovered(slant):
    """Fronto-parallel and 45-degree slanted planes: depth within 0.5 % (median) and normals
    within 5 degrees (median); the slanted normal is far from fronto-parallel, so it must be found."""
    plane = _plane(slant)
    views, depths, poses = plane_scene(plane, CENTERS3, np.array([0, 0, 2.0]), CAM.K, W, H)
    dm = estimate_depth_map(views[0], views[1:], _range(depths[0]), FAST, device="cpu")
    n_cam = poses[0][:3, :3].T @ plane.normal / np.linalg.norm(plane.normal)
    m, rel, ang = _errors(dm, depths[0], n_cam)
    assert m.mean() > 0.75
    assert np.median(rel) < 0.005
    assert np.percentile(rel, 90) < 0.05  # the 10 % worst are mostly at the image borders
    assert np.median(ang) < 5.0
    # normals point to the camera
    rays = CAM.pixel_rays()
    assert ((dm.normal * rays).sum(-1)[m] < 0).all()


def test_two_views_recover_the_overlap():
    plane = _plane(20.0)
    views, depths, poses = plane_scene(plane, CENTERS3[:2], np.array([0, 0, 2.0]), CAM.K, W, H)
    dm = estimate_depth_map(views[0], views[1:], _range(depths[0]), FAST, device="cpu")
    n_cam = poses[0][:3, :3].T @ plane.normal / np.linalg.norm(plane.normal)
    m, rel, ang = _errors(dm, depths[0], n_cam)
    assert m.mean() > 0.6  # the source sees the left part of the reference only partly
    assert np.median(rel) < 0.005
    assert np.median(ang) < 6.0


def test_no_overlapping_source_gives_empty_map_with_warning(caplog):
    plane = _plane(0.0)
    views, _, _ = plane_scene(plane, CENTERS3[:1], np.array([0, 0, 2.0]), CAM.K, W, H)
    # a source camera behind the reference, looking away from the plane
    T_away = look_at(np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, -3.0]), up=(0.0, -1.0, 0.0))
    from evdense.testing.mvs_scenes import view_from_pose

    away = view_from_pose(views[0].image, CAM.K, T_away)
    with caplog.at_level(logging.WARNING, logger="evdense"):
        dm = estimate_depth_map(views[0], [away], (1.0, 4.0), FAST, device="cpu", name="ref")
    assert dm.depth.shape == (H, W) and not dm.depth.any()
    assert not dm.normal.any()
    assert any("no source view overlaps" in r.message for r in caplog.records)


def test_textureless_pixels_stay_unmatched():
    plane = _plane(0.0)
    views, _, _ = plane_scene(plane, CENTERS3, np.array([0, 0, 2.0]), CAM.K, W, H)
    from dataclasses import replace

    flat = replace(views[0], image=np.full_like(views[0].image, 0.5))
    dm = estimate_depth_map(flat, views[1:], (1.0, 4.0), FAST, device="cpu")
    assert (dm.cost == 2.0).all() and not dm.depth.any()


def test_geometric_pass_and_filter():
    """Maps of three views, then the geometric pass and filter of the middle view: kept pixels are
    accurate and agree with the other views; corrupting the sources' depths removes them."""
    plane = _plane(30.0)
    views, depths, poses = plane_scene(plane, CENTERS3, np.array([0, 0, 2.0]), CAM.K, W, H)
    maps = []
    for i in range(3):
        src = [views[j] for j in range(3) if j != i]
        maps.append(estimate_depth_map(views[i], src, _range(depths[i]), FAST, device="cpu"))
    src_depths = [np.where(m.cost < 0.5, m.depth, 0) for m in maps[1:]]
    geo = estimate_depth_map(
        views[0],
        views[1:],
        _range(depths[0]),
        PatchMatchConfig(iterations=[3, 2, 1], geom_iterations=1),
        init=maps[0],
        source_depths=src_depths,
        device="cpu",
    )
    fc = FilterConfig(max_cost=0.5, min_consistent_views=1, min_triangulation_angle=1.0)
    kept, counts = filter_depth_map(
        views[0], views[1:], geo, fc, source_depths=src_depths, device="cpu"
    )
    m = kept.depth > 0
    assert m.mean() > 0.5
    rel = np.abs(kept.depth[m] - depths[0][m]) / depths[0][m]
    assert np.percentile(rel, 99) < 0.02  # the filter removes the gross errors
    assert (counts[m] >= 1).all()
    # sources 10 % too far: nothing agrees any more
    bad = [d * 1.1 for d in src_depths]
    kept_bad, _ = filter_depth_map(views[0], views[1:], geo, fc, source_depths=bad, device="cpu")
    assert (kept_bad.depth > 0).mean() < 0.02
    # a triangulation angle above what the cameras offer removes everything
    wide = FilterConfig(max_cost=0.5, min_consistent_views=1, min_triangulation_angle=30.0)
    kept_wide, _ = filter_depth_map(
        views[0], views[1:], geo, wide, source_depths=src_depths, device="cpu"
    )
    assert not kept_wide.depth.any()


def test_same_seed_same_map():
    views, _, _ = plane_scene(_plane(10.0), CENTERS3, np.array([0, 0, 2.0]), CAM.K, W, H)
    cfg = PatchMatchConfig(iterations=[2, 1], seed=3)
    a = estimate_depth_map(views[0], views[1:], (1.0, 4.0), cfg, device="cpu")
    b = estimate_depth_map(views[0], views[1:], (1.0, 4.0), cfg, device="cpu")
    np.testing.assert_array_equal(a.depth, b.depth)


def test_bad_inputs_raise():
    views, _, _ = plane_scene(_plane(0.0), CENTERS3, np.array([0, 0, 2.0]), CAM.K, W, H)
    with pytest.raises(ValueError, match="depth range"):
        estimate_depth_map(views[0], views[1:], (2.0, 1.0), FAST, device="cpu")
    with pytest.raises(ValueError, match="propagation_distances"):
        estimate_depth_map(
            views[0], views[1:], (1.0, 4.0), PatchMatchConfig(propagation_distances=[2])
        )


def _tiny_workspace(tmp_path):
    """Frames and a known COLMAP model of four views of a 20-degree plane."""
    import imageio.v3 as iio

    from evdense.mvs.oracle import sample_tracks, write_known_model

    plane = _plane(20.0)
    centers = [*CENTERS3, np.array([0.0, 0.2, 0.0])]
    views, depths, poses = plane_scene(plane, centers, np.array([0, 0, 2.0]), CAM.K, W, H)
    frames = tmp_path / "frames"
    frames.mkdir()
    names = [f"{i:06d}.png" for i in range(len(views))]
    for n, v in zip(names, views, strict=True):
        iio.imwrite(frames / n, (v.image * 255).round().astype(np.uint8))
    P, tracks = sample_tracks(np.stack(depths), CAM, np.stack(poses), 12, 0.01)
    write_known_model(tmp_path / "sparse", CAM, names, np.stack(poses), P, tracks)
    return plane, frames, tmp_path / "sparse"


STAGE_CONF = {
    "patch_match": {"iterations": [3, 2, 1]},
    "view_selection": {"num_source_views": 3, "min_shared_points": 3},
    "filter": {"min_consistent_views": 1},
}


def test_stage_on_a_tiny_workspace(tmp_path):
    """run_mvs end to end on four views of a plane with a known COLMAP model: fused points on the
    plane, stats written, and a second run reuses every map."""
    from evdense.formats.cloud import read_cloud
    from evdense.mvs.stage import run_mvs

    plane, frames, sparse = _tiny_workspace(tmp_path)
    out = tmp_path / "mvs"
    stats = run_mvs(sparse, frames, out, STAGE_CONF, threads=1)
    assert (out / "fused.ply").is_file() and (out / "fused.ply.vis").is_file()
    assert stats["fused_points"] > 2000
    assert json.loads((out / "stats.json").read_text())["num_views"] == 4
    X = read_cloud(out / "fused.ply").points
    n = plane.normal / np.linalg.norm(plane.normal)
    dist = np.abs((X - plane.point) @ n)
    assert np.median(dist) < 0.01 and np.percentile(dist, 95) < 0.05
    assert (out / "stereo" / "previews" / "000000.png.geometric.depth.png").is_file()
    # resumable: nothing is recomputed
    mt = {p: p.stat().st_mtime_ns for p in (out / "stereo" / "depth_maps").iterdir()}
    run_mvs(sparse, frames, out, STAGE_CONF, threads=1)
    assert {p: p.stat().st_mtime_ns for p in (out / "stereo" / "depth_maps").iterdir()} == mt


@pytest.mark.slow
def test_stage_worker_processes_compute_the_same_maps(tmp_path):
    """threads=2 on the CPU: two worker processes; seeds are per view, so the maps are identical."""
    from evdense.mvs.maps_io import read_colmap_array
    from evdense.mvs.stage import run_mvs

    _, frames, sparse = _tiny_workspace(tmp_path)
    run_mvs(sparse, frames, tmp_path / "one", STAGE_CONF, threads=1)
    run_mvs(sparse, frames, tmp_path / "two", STAGE_CONF, threads=2)
    maps = sorted((tmp_path / "one" / "stereo" / "depth_maps").iterdir())
    assert len(maps) == 8
    for p in maps:
        np.testing.assert_array_equal(
            read_colmap_array(p),
            read_colmap_array(tmp_path / "two" / "stereo" / "depth_maps" / p.name),
        )
