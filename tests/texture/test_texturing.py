"""Texturing (view selection, atlas, seam levelling, export) and renders, on a known cube seen
from known cameras."""

from __future__ import annotations

import json

import numpy as np
import open3d as o3d
import pytest
from scipy.ndimage import binary_erosion

from evdense.camera import Camera
from evdense.evaluate.rendering import depth_map, render_mesh, render_points, render_textured
from evdense.mesh.geometry import face_adjacency, face_normals
from evdense.mesh.views import make_mesh, read_views, write_workspace
from evdense.poses import look_at
from evdense.testing.mesh_scenes import (
    box_mesh,
    make_views,
    orbit_poses,
    render_colour,
    sphere_mesh,
)
from evdense.texture import (
    TextureConfig,
    read_textured_mesh,
    select_views,
    texture_mesh_views,
    view_candidates,
    write_textured_mesh,
)
from evdense.texture.stage import run_texture

BASE = np.array(
    [
        [0.9, 0.2, 0.2],
        [0.2, 0.8, 0.2],
        [0.2, 0.3, 0.9],
        [0.9, 0.9, 0.2],
        [0.8, 0.3, 0.8],
        [0.2, 0.8, 0.8],
    ]
)
CAM = Camera(96, 72, 90.0, 90.0, 47.5, 35.5)


def cube_colour(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """A known colour per cube side (by its outward axis), modulated by a smooth pattern."""
    axis = np.argmax(np.abs(n), axis=1)
    side = axis * 2 + (n[np.arange(len(n)), axis] > 0)
    return BASE[side] * (0.75 + 0.25 * np.sin(8 * p.sum(1)))[:, None]


@pytest.fixture(scope="module")
def cube():
    v, f = box_mesh(1.0, 4)
    poses = np.concatenate(
        [orbit_poses(6, 3.0, elevation_deg=30), orbit_poses(6, 3.0, elevation_deg=-30, phase=0.5)]
    )
    views = make_views(v, f, CAM, poses, cube_colour)
    return v, f, views


HELD_OUT = look_at(np.array([2.0, -2.2, 1.5]), np.zeros(3))


def interior_psnr(img: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    m = binary_erosion(mask, iterations=2)
    return float(10 * np.log10(1.0 / np.mean((img[m] - gt[m]) ** 2)))


def test_textured_cube_reproduces_the_known_colours(cube):
    v, f, views = cube
    tm = texture_mesh_views(v, f, views, TextureConfig())
    assert np.all(tm.face_view >= 0)  # every face is seen by some view
    # The atlas at each face centre holds that face's known colour.
    fn, _ = face_normals(v, f)
    cent = v[f].mean(axis=1)
    got = tm.sample(np.arange(len(f)), np.full((len(f), 2), 1.0 / 3.0))
    want = cube_colour(cent, fn)
    assert np.abs(got - want).max() < 0.06
    assert np.abs(got - want).mean() < 0.015
    # Rendered back from a camera that took no picture, it matches the GT image.
    gt, _ = render_colour(v, f, CAM, HELD_OUT, cube_colour, supersample=2)
    img, mask = render_textured(tm, CAM, HELD_OUT)
    assert mask.sum() > 1000
    assert interior_psnr(img, gt, mask) > 30.0


def test_view_selection_prefers_large_projections_and_smoothness_merges_charts(cube):
    v, f, views = cube
    F = len(f)
    cand = view_candidates(v, f, views)
    adj = face_adjacency(f)
    best = select_views(F, cand, adj, smoothness=0.0)
    # Without smoothness each face takes the view where it projects largest.
    fc, vc, q = cand
    for face in (0, 50, 150):
        sel = fc == face
        assert best[face] == vc[sel][np.argmax(q[sel])]
    smooth = select_views(F, cand, adj, smoothness=2.0)
    changes = lambda lab: int(np.sum(lab[adj[:, 0]] != lab[adj[:, 1]]))  # noqa: E731
    assert changes(smooth) < changes(best)
    # Every chosen view really sees its face.
    ok = set(zip(fc.tolist(), vc.tolist(), strict=True))
    assert all((i, int(lab)) in ok for i, lab in enumerate(smooth))


def test_seam_levelling_evens_out_exposure_differences(cube):
    v, f, views = cube
    # Each view gets its own exposure gain (0.85 .. 1.18).
    gained = make_views(v, f, CAM, views.poses, cube_colour)
    gained.images = [np.clip(im * (0.85 + 0.03 * i), 0, 1) for i, im in enumerate(gained.images)]
    fn, _ = face_normals(v, f)
    adj = face_adjacency(f)

    def seam_jump(tm) -> float:
        a, b = adj[:, 0], adj[:, 1]
        seam = (tm.face_view[a] != tm.face_view[b]) & (np.einsum("ij,ij->i", fn[a], fn[b]) > 0.99)
        a, b = a[seam], b[seam]
        jumps = []
        for fa, fb in zip(a, b, strict=True):
            shared = np.intersect1d(f[fa], f[fb])
            mid = v[shared].mean(0)
            cols = []
            for face in (fa, fb):
                # barycentrics of the edge midpoint in this face
                w = np.array([np.isin(f[face][k], shared) * 0.5 for k in range(3)])
                cols.append(tm.sample(np.array([face]), w[None, 1:]))
                assert np.allclose(w @ v[f[face]], mid)
            jumps.append(np.abs(cols[0] - cols[1]).max())
        return float(np.mean(jumps))

    plain = texture_mesh_views(v, f, gained, TextureConfig(level_seams=False))
    levelled = texture_mesh_views(v, f, gained, TextureConfig(level_seams=True))
    assert np.array_equal(plain.face_view, levelled.face_view)
    assert seam_jump(levelled) < 0.5 * seam_jump(plain)
    gt, _ = render_colour(v, f, CAM, HELD_OUT, cube_colour, supersample=2)
    img, mask = render_textured(plain, CAM, HELD_OUT)
    p_plain = interior_psnr(img, gt, mask)
    img, mask = render_textured(levelled, CAM, HELD_OUT)
    assert interior_psnr(img, gt, mask) > p_plain + 3.0


def test_faces_no_view_sees_get_a_flat_colour():
    v, f = box_mesh(1.0, 2)
    views = make_views(v, f, CAM, orbit_poses(4, 3.0, elevation_deg=40), cube_colour)
    tm = texture_mesh_views(v, f, views)
    fn, _ = face_normals(v, f)
    bottom = fn[:, 2] < -0.99
    assert np.all(tm.face_view[bottom] == -1) and np.all(tm.face_view[~bottom] >= 0)
    # Flat: the texture coordinates of an unseen face collapse to one texel.
    assert np.allclose(tm.face_uvs[bottom].std(axis=1), 0)
    assert np.all(np.isfinite(tm.vertex_colors))


def test_export_round_trip_and_stage(tmp_path, cube):
    v, f, views = cube
    tm = texture_mesh_views(v, f, views)
    files = write_textured_mesh(tmp_path / "t", tm)
    back = read_textured_mesh(files["obj"])
    assert np.allclose(back.vertices, tm.vertices, atol=1e-6) and np.array_equal(
        back.faces, tm.faces
    )
    a, _ = render_textured(tm, CAM, HELD_OUT)
    b, _ = render_textured(back, CAM, HELD_OUT)
    assert np.abs(a - b).max() < 2.5 / 255  # 8-bit PNG quantisation only
    # Other readers open it: open3d finds the texture coordinates and the image.
    m = o3d.io.read_triangle_mesh(str(files["obj"]), True)
    assert m.has_triangle_uvs() and m.has_textures() and len(m.triangles) == len(f)
    glb = o3d.io.read_triangle_mesh(str(files["glb"]), True)
    assert glb.has_triangle_uvs() and glb.has_textures() and len(glb.triangles) == len(f)
    assert np.allclose(np.asarray(glb.triangle_uvs), tm.face_uvs.reshape(-1, 2), atol=1e-6)
    ply = o3d.io.read_triangle_mesh(str(files["ply"]))
    assert ply.has_vertex_colors() and len(ply.vertices) == len(v)
    # The stage: a dense workspace on disk in, a textured/ folder out.
    ws = tmp_path / "ws"
    write_workspace(ws, views)
    # COLMAP's pixel convention differs from ours by half a pixel: read back, cameras are exact.
    back_views = read_views(ws)
    assert back_views.cameras == views.cameras
    np.testing.assert_allclose(back_views.poses, views.poses, atol=1e-9)
    mesh_path = tmp_path / "mesh.ply"
    o3d.io.write_triangle_mesh(str(mesh_path), make_mesh(v, f))
    out = run_texture(mesh_path, ws, tmp_path / "textured", {"smoothness": 0.5})
    assert {p.name for p in out.iterdir()} == {
        "mesh.obj",
        "mesh.mtl",
        "mesh_texture.png",
        "mesh_colored.ply",
        "texture.json",
        "mesh.glb",
    }
    assert json.loads((out / "texture.json").read_text())["faces_unseen"] == 0
    img, mask = render_textured(read_textured_mesh(out / "mesh.obj"), CAM, HELD_OUT)
    gt, _ = render_colour(v, f, CAM, HELD_OUT, cube_colour, supersample=2)
    assert interior_psnr(img, gt, mask) > 28.0
    # through the disk as good as in memory (a half-pixel camera error costs several dB here)
    assert interior_psnr(img, gt, mask) > interior_psnr(a, gt, mask) - 0.5
    assert not (tmp_path / "textured.partial").exists()
    # the same stage from the command line (python -m evdense.texture), with a config file
    from evdense.texture.__main__ import main

    (tmp_path / "c.yaml").write_text("mesh:\n  texture:\n    smoothness: 0.5\n")
    main(["--config", str(tmp_path / "c.yaml"), str(ws), str(mesh_path), str(tmp_path / "cli")])
    for name in ("mesh.obj", "mesh_texture.png", "texture.json"):
        assert (tmp_path / "cli" / name).read_bytes() == (out / name).read_bytes(), name
    with pytest.raises(ValueError, match="nothing.ply"):
        run_texture(tmp_path / "nothing.ply", ws, tmp_path / "t2")


def test_renders_of_mesh_and_cloud():
    v, f = sphere_mesh(1.0, 40)
    mesh = make_mesh(v, f)
    cam = Camera(81, 61, 80.0, 80.0, 40.0, 30.0)
    T = look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))
    depth = depth_map(mesh, cam, T)
    assert abs(depth[30, 40] - 3.0) < 0.01 and np.isinf(depth[0, 0])
    img = render_mesh(mesh, cam, T, "lambert")
    assert img[30, 40, 0] > 0.95 and img[0, 0, 0] == 0.0
    assert img[30, 40, 0] > img[30, 58, 0]  # Lambert falls off towards the rim
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.tile([0.2, 0.4, 0.6], (len(v), 1)))
    col = render_mesh(mesh, cam, T, "vertex_colors")
    assert np.allclose(col[30, 40], [0.2, 0.4, 0.6], atol=1e-6)
    with pytest.raises(ValueError, match="shading"):
        render_mesh(mesh, cam, T, "phong")
    # A cloud: the front point wins the z-buffer.
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    splat = render_points(pts, cam, T, colors=np.array([[1.0, 0, 0], [0, 1.0, 0]]), radius=1)
    assert np.allclose(splat[30, 40], [1, 0, 0]) and np.allclose(splat[29, 39], [1, 0, 0])
    assert splat.sum() == pytest.approx(9 * 1.0)


def test_atlas_is_scaled_down_to_its_size_limit(cube):
    v, f, views = cube
    full = texture_mesh_views(v, f, views)
    small = texture_mesh_views(v, f, views, TextureConfig(max_atlas_size=64))
    assert max(small.atlas.shape[:2]) <= 1.1 * 64 < max(full.atlas.shape[:2])
    gt, _ = render_colour(v, f, CAM, HELD_OUT, cube_colour, supersample=2)
    img, mask = render_textured(small, CAM, HELD_OUT)
    p_small = interior_psnr(img, gt, mask)
    img, mask = render_textured(full, CAM, HELD_OUT)
    assert 22.0 < p_small < interior_psnr(img, gt, mask)
