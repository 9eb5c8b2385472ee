"""Surface reconstruction: the visibility (Delaunay + graph-cut) mesher, Poisson, clean-up and the
mesh_surface stage, on exact geometry built here (spheres, cubes, known cameras)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
import yaml

from evdense.camera import Camera
from evdense.formats.cloud import read_cloud, read_vis_file, write_vis_file
from evdense.mesh.cleanup import (
    CleanupConfig,
    boundary_vertices,
    clean_mesh,
    close_small_holes,
    loop_nonplanarity,
    smooth_taubin,
)
from evdense.mesh.geometry import face_adjacency, face_normals
from evdense.mesh.poisson import PoissonConfig, poisson_mesh
from evdense.mesh.stage import MeshConfig, run_mesh
from evdense.mesh.views import Views, make_mesh, read_mesh, write_workspace
from evdense.mesh.visibility import (
    estimate_visibility,
    merge_points,
    visibility_mesh,
)
from evdense.poses import look_at
from evdense.testing.mesh_scenes import (
    box_mesh,
    make_views,
    sample_cloud,
    smooth_colour,
    sphere_mesh,
)

CAM = Camera(160, 120, 120.0, 120.0, 79.5, 59.5)


def ring_views(n: int = 16, radius: float = 4.0) -> Views:
    """Cameras around the origin at varied elevations, plus one above and one below."""
    poses = []
    for k in range(n):
        th = 2 * np.pi * k / n
        el = 0.6 * np.sin(3 * th)
        eye = radius * np.array([np.cos(th) * np.cos(el), np.sin(th) * np.cos(el), np.sin(el)])
        poses.append(look_at(eye, np.zeros(3)))
    for z in (radius, -radius):
        poses.append(look_at(np.array([0.0, 0.0, z]), np.zeros(3), up=(1.0, 0.0, 0.0)))
    return Views([CAM] * len(poses), np.stack(poses))


def noisy_sphere(n: int, noise: float, n_outliers: int, rng: np.random.Generator):
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    normals = p.copy()
    pts = p + rng.normal(scale=noise, size=p.shape)
    out = rng.uniform(-2, 2, size=(n_outliers, 3))
    out = out[np.linalg.norm(out, axis=1) > 1.15]  # in free space around the sphere
    on = rng.normal(size=out.shape)
    on /= np.linalg.norm(on, axis=1, keepdims=True)
    return np.concatenate([pts, out]), np.concatenate([normals, on]), len(out)


def test_visibility_recovers_sphere_and_ignores_outliers(rng):
    pts, nrm, n_out = noisy_sphere(20000, 0.005, 1500, rng)
    views = ring_views()
    vis = estimate_visibility(pts, nrm, views)
    raw = visibility_mesh(pts, vis, views.centers)
    mesh = clean_mesh(raw, CleanupConfig(target_faces=0))
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.triangles)
    # Accuracy: the surface lies on the unit sphere (diameter 2) within 1% of the size on average.
    s = np.asarray(mesh.sample_points_uniformly(20000).points)
    err = np.abs(np.linalg.norm(s, axis=1) - 1.0)
    assert err.mean() < 0.01 * 2.0
    assert np.percentile(err, 99) < 0.03
    # Outliers are not surface: no vertex farther than 4% of the size from the sphere.
    assert np.abs(np.linalg.norm(v, axis=1) - 1.0).max() < 0.08
    # Completeness: every direction is covered (GT samples close to the mesh).
    d = o3d.t.geometry.RaycastingScene()
    d.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    gt = rng.normal(size=(5000, 3))
    gt /= np.linalg.norm(gt, axis=1, keepdims=True)
    comp = d.compute_distance(o3d.core.Tensor(gt.astype(np.float32))).numpy()
    assert np.percentile(comp, 99) < 0.03
    # Oriented outwards.
    fn, _ = face_normals(v, f)
    assert np.mean(np.einsum("ij,ij->i", fn, v[f].mean(1)) > 0) > 0.97
    # The raw mesh's stray components (outliers) are small, and clean-up removed them.
    labels, counts, _ = mesh.cluster_connected_triangles()
    assert len(counts) == 1


def test_visibility_recovers_cube_corners(rng):
    v, f = box_mesh(1.5, 6)
    pts, nrm = sample_cloud(v, f, 20000, noise=0.003, outliers=0.03, seed=1)
    views = ring_views()
    vis = estimate_visibility(pts, nrm, views)
    mesh = clean_mesh(visibility_mesh(pts, vis, views.centers), CleanupConfig(target_faces=0))
    s = np.asarray(mesh.sample_points_uniformly(20000).points)
    dist = np.max(np.abs(s), axis=1) - 0.75  # signed distance to the cube along the max-norm
    assert np.abs(dist).mean() < 0.01 * 1.5
    assert np.percentile(np.abs(dist), 99) < 0.04
    # The cube's 8 corners are all reached (within 5% of the side).
    corners = 0.75 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    dc = np.linalg.norm(corners[:, None] - np.asarray(mesh.vertices)[None], axis=2).min(1)
    assert dc.max() < 0.075


def test_estimate_visibility_respects_occlusion_and_facing(rng):
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    views = Views([CAM], look_at(np.array([0.0, 0.0, 4.0]), np.zeros(3), up=(1.0, 0.0, 0.0))[None])
    vis = estimate_visibility(p, p.copy(), views)
    seen = np.array([len(v) == 1 for v in vis])
    assert not seen[p[:, 2] < 0].any()  # the far side is never seen
    assert seen[p[:, 2] > 0.5].mean() > 0.95
    # Without normals the far side is hidden by the z-buffer alone.
    vis = estimate_visibility(p, None, views)
    seen = np.array([len(v) == 1 for v in vis])
    assert seen[p[:, 2] < -0.3].mean() < 0.05
    assert seen[p[:, 2] > 0.5].mean() > 0.9


def test_merge_points_caps_the_count(rng):
    p = rng.uniform(size=(5000, 3))
    merged, rep = merge_points(p, 1000, 0.01)
    assert len(merged) <= 1000 and len(rep) == len(merged)
    assert merged.min() >= 0 and merged.max() <= 1
    same, idx = merge_points(p, 10000, 0.01)
    assert same is p and np.array_equal(idx, np.arange(5000))


def test_poisson_is_trimmed_to_the_data(rng):
    # An open hemisphere: untrimmed Poisson would close it; trimming keeps only supported surface.
    p = rng.normal(size=(15000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    p = p[p[:, 2] > 0]
    mesh = poisson_mesh(p, p.copy(), PoissonConfig(depth=7))
    c = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)].mean(1)
    assert c[:, 2].min() > -0.1  # nothing invented under the open side
    s = np.asarray(mesh.sample_points_uniformly(10000).points)
    assert np.abs(np.linalg.norm(s, axis=1) - 1).mean() < 0.01


def test_close_small_holes_makes_a_sphere_watertight():
    v, f = sphere_mesh(1.0, 20)
    mesh = make_mesh(v, f)
    pair = face_adjacency(f)
    pair = pair[pair[:, 0] == 500][0]
    mesh.remove_triangles_by_index(pair.tolist())  # a small hole (two adjacent faces, 4 edges)
    mesh.remove_unreferenced_vertices()
    assert not mesh.is_watertight()
    closed = close_small_holes(mesh, 10)
    assert closed.is_watertight() and closed.is_orientable()
    # A hole larger than the limit stays open.
    assert not close_small_holes(mesh, 3).is_watertight()


def grid_mesh(n: int, height=lambda x, y: 0.0 * x) -> tuple[np.ndarray, np.ndarray]:
    """An ``n x n`` vertex grid over the unit square, z = height(x, y), two faces per cell."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), height(x, y).ravel()], axis=1)
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def punch(v, f, inside) -> o3d.geometry.TriangleMesh:
    """The mesh without the faces whose centroid satisfies ``inside``."""
    keep = ~inside(v[f].mean(1))
    mesh = make_mesh(v, f[keep])
    mesh.remove_unreferenced_vertices()
    return mesh


def open_boundary_vertices(mesh) -> int:
    f = np.asarray(mesh.triangles)
    return len(boundary_vertices(f))


def test_loop_nonplanarity_separates_flat_and_bent_loops():
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    flat = np.stack([np.cos(t), np.sin(t), 0 * t], 1)
    saddle = np.stack([np.cos(t), np.sin(t), 0.7 * np.cos(2 * t)], 1)
    assert loop_nonplanarity(flat) < 1e-9
    assert (
        loop_nonplanarity(flat @ np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0])
        < 1e-9
    )
    assert loop_nonplanarity(saddle) > 0.3


def test_only_small_planar_holes_are_closed():
    v, f = grid_mesh(21)  # unit square, edges 0.05
    # A 2x2-cell hole in a plane (8 edges, 8 median-ish edges of perimeter) is closed.
    small = punch(v, f, lambda c: (np.abs(c[:, 0] - 0.5) < 0.05) & (np.abs(c[:, 1] - 0.5) < 0.05))
    n_open = open_boundary_vertices(small)
    closed = close_small_holes(small, 40)
    assert open_boundary_vertices(closed) == n_open - 8  # only the outer border is left
    assert np.abs(np.asarray(closed.vertices)[:, 2]).max() == 0
    # The same hole with the edge limit below its length stays open.
    assert open_boundary_vertices(close_small_holes(small, 7)) == n_open
    # A 12x12-cell hole has 48 edges: over 40 edges, left open.
    big = punch(v, f, lambda c: (np.abs(c[:, 0] - 0.5) < 0.3) & (np.abs(c[:, 1] - 0.5) < 0.3))
    assert open_boundary_vertices(close_small_holes(big, 40)) == open_boundary_vertices(big)


def square_ring() -> tuple[np.ndarray, np.ndarray]:
    """Eight faces between the unit square and the square [0.3, 0.7]^2: a 4-edge hole of
    perimeter 1.6 in the middle."""
    outer = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    inner = 0.3 + 0.4 * outer
    v = np.concatenate([np.c_[outer, np.zeros(4)], np.c_[inner, np.zeros(4)]])
    f = [[k, (k + 1) % 4, 4 + (k + 1) % 4] for k in range(4)]
    f += [[k, 4 + (k + 1) % 4, 4 + k] for k in range(4)]
    return v, np.array(f)


def test_a_hole_of_few_long_edges_is_left_open():
    # Alone, the ring's edges are all long: the 4-edge hole is small in median edges and closed.
    v, f = square_ring()
    assert len(close_small_holes(make_mesh(v, f), 40).triangles) > len(f)
    # Next to a fine surface (median edge 0.005, so at most 0.2 of perimeter), the same 4-edge
    # hole is 320 median edges around: it is an opening, not a pinhole, and stays open.
    gv, gf = grid_mesh(21)
    gv = 0.1 * gv + [0, 0, 5]
    mesh = make_mesh(np.concatenate([v, gv]), np.concatenate([f, gf + len(v)]))
    assert len(close_small_holes(mesh, 40).triangles) == len(f) + len(gf)


def test_a_bent_hole_is_left_open():
    # A hole across a ridge: the boundary bends around the fold (nonplanarity ~0.35), so a fan
    # would cut the corner; it is left open. The same hole on the flat grid is closed.
    ridge = lambda x, y: 1.0 - 2 * np.abs(x - 0.5)  # noqa: E731
    v, f = grid_mesh(21, ridge)
    hole = lambda c: (np.abs(c[:, 0] - 0.5) < 0.15) & (np.abs(c[:, 1] - 0.5) < 0.15)  # noqa: E731
    bent = punch(v, f, hole)
    assert open_boundary_vertices(close_small_holes(bent, 40)) == open_boundary_vertices(bent)
    assert open_boundary_vertices(
        close_small_holes(bent, 40, max_nonplanarity=1.0)
    ) < open_boundary_vertices(bent)
    flat = punch(*grid_mesh(21), hole)
    assert open_boundary_vertices(close_small_holes(flat, 40)) < open_boundary_vertices(flat)


def test_taubin_smoothing_border_modes(rng):
    v, f = grid_mesh(21)
    noisy = v + np.concatenate([np.zeros((len(v), 2)), 0.01 * rng.normal(size=(len(v), 1))], 1)
    noisy[10, 2] += 0.1  # a spike on the border (vertex 10 is the middle of the edge x = 0)
    border = boundary_vertices(f)
    assert len(border) == 80 and 10 in border
    inner = np.setdiff1d(np.arange(len(v)), border)
    moved = {}
    for mode in ("curve", "pinned", "free"):
        out = smooth_taubin(noisy, f, 5, boundary=mode)
        assert np.abs(out[inner, 2]).mean() < 0.5 * np.abs(noisy[inner, 2]).mean(), mode
        moved[mode] = np.linalg.norm(out[border, :2] - noisy[border, :2], axis=1).mean()
        spike = out[10, 2]
        if mode == "pinned":  # the border stays exactly where it was, spike included
            assert moved[mode] == 0 and spike == noisy[10, 2]
        else:  # the spike is smoothed away
            assert spike < 0.5 * noisy[10, 2], mode
    # Free, the border is pulled inwards (the square shrinks); along the curve only its corners round.
    assert moved["free"] > 0.005
    assert moved["curve"] < 0.3 * moved["free"]
    with pytest.raises(ValueError, match="boundary"):
        smooth_taubin(noisy, f, 1, boundary="fixed")
    # A closed surface has no boundary: a smoothed sphere keeps its size (Taubin does not shrink).
    sv, sf = sphere_mesh(1.0, 20)
    r = np.linalg.norm(smooth_taubin(sv, sf, 5), axis=1)
    assert abs(r.mean() - 1) < 0.01


def test_clean_mesh_removes_small_components_and_decimates():
    v1, f1 = sphere_mesh(1.0, 30)
    v2, f2 = sphere_mesh(0.05, 4)
    v = np.concatenate([v1, v2 + 3.0])
    f = np.concatenate([f1, f2 + len(v1)])
    out = clean_mesh(make_mesh(v, f), CleanupConfig(target_faces=500, smooth_iterations=0))
    assert np.linalg.norm(np.asarray(out.vertices), axis=1).max() < 1.01
    assert 400 <= len(out.triangles) <= 500


def test_mesh_config_refuses_unknown_keys_and_leaves_the_later_stages_sections():
    with pytest.raises(ValueError, match="mesh.visibility"):
        MeshConfig.from_dict({"visibility": {"no_such_key": 1}})
    with pytest.raises(ValueError, match="no_such_key"):
        MeshConfig.from_dict({"no_such_key": 1})
    conf = MeshConfig.from_dict({"method": "poisson", "refine": {"x": 1}, "texture": {}})
    assert conf.method == "poisson"


def test_mesh_surface_stage_from_a_workspace(tmp_path, rng):
    v, f = sphere_mesh(1.0, 30)
    views = make_views(
        v, f, Camera(64, 48, 50.0, 50.0, 31.5, 23.5), ring_views(8).poses, smooth_colour
    )
    ws = tmp_path / "mvs" / "gt"
    write_workspace(ws, views)
    pts, nrm = sample_cloud(v, f, 8000, noise=0.003, seed=2)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.normals = o3d.utility.Vector3dVector(nrm)
    pcd.colors = o3d.utility.Vector3dVector(smooth_colour(pts))
    cloud = ws / "fused.ply"
    o3d.io.write_point_cloud(str(cloud), pcd)
    conf = {"cleanup": {"target_faces": 3000}, "poisson": {"depth": 7}}
    # Estimated visibility (no .vis file).
    out = run_mesh(cloud, ws, tmp_path / "vis" / "mesh.ply", "visibility", conf)
    m = read_mesh(out)
    assert 2000 < len(m.triangles) <= 3000 and m.has_vertex_colors()
    r = np.linalg.norm(np.asarray(m.vertices), axis=1)
    assert np.abs(r - 1).mean() < 0.01
    # With a .vis file (COLMAP's format), read back exactly.
    vis = estimate_visibility(pts, nrm, views)
    write_vis_file(str(cloud) + ".vis", vis)
    back = read_vis_file(str(cloud) + ".vis")
    assert all(np.array_equal(a, b) for a, b in zip(vis, back, strict=True))
    assert read_cloud(cloud).visibility is not None
    out_vis = out = run_mesh(cloud, ws, tmp_path / "vis2" / "mesh.ply", "visibility", conf)
    assert np.abs(np.linalg.norm(np.asarray(read_mesh(out).vertices), axis=1) - 1).mean() < 0.01
    out = run_mesh(cloud, ws, tmp_path / "poisson" / "mesh.ply", "poisson", conf)
    assert np.abs(np.linalg.norm(np.asarray(read_mesh(out).vertices), axis=1) - 1).mean() < 0.01
    # the same stage from the command line (python -m evdense.mesh), with a config file
    from evdense.mesh.__main__ import main

    (tmp_path / "c.yaml").write_text(yaml.safe_dump({"mesh": conf}))
    main(["--config", str(tmp_path / "c.yaml"), str(ws), str(tmp_path / "cli.ply")])
    assert (tmp_path / "cli.ply").read_bytes() == out_vis.read_bytes()
    assert not list(tmp_path.rglob("*.partial*"))
    # Bad inputs name the file.
    with pytest.raises(ValueError, match="nothing.ply"):
        run_mesh(tmp_path / "nothing.ply", ws, tmp_path / "x.ply", "visibility", conf)
    with pytest.raises(ValueError, match="sparse"):
        run_mesh(cloud, tmp_path, tmp_path / "x.ply", "visibility", conf)
    with pytest.raises(ValueError, match="method"):
        run_mesh(cloud, ws, tmp_path / "x.ply", "marching", conf)
    write_vis_file(str(cloud) + ".vis", [np.array([99])] * len(pts))
    with pytest.raises(ValueError, match="registered views"):
        run_mesh(cloud, ws, tmp_path / "x.ply", "visibility", conf)
    assert not (tmp_path / "x.ply").exists()
