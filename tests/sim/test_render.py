"""The ray-cast renderer: depth, UV mapping, texture filtering, supersampling, HDR lights."""

from __future__ import annotations

import numpy as np
import pytest

from evdense.poses import look_at
from evdense.sim.render import HAVE_NUMBA, Renderer
from evdense.sim.scene import load_scene

CAM = {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 23.5}
EYE = np.array([0.0, 0.0, 1.5])
T_FRONT = look_at(EYE, EYE + [0.0, 1.0, 0.0])  # looking along +y, level


def _plane_scene(
    distance: float,
    checker: dict,
    tile_m: float,
    room: float = 100.0,
    camera=None,
    render=None,
    size=8.0,
):
    """A fronto-parallel textured ``size`` x ``size`` m plane ``distance`` m in front of T_FRONT, inside a room."""
    spec = {
        "shading": {"ambient": 1.0},  # no key light: radiance = reflectance
        "materials": {
            "bg": {"texture": {"type": "constant", "value": 0.5}},
            "chk": {"texture": {"type": "checker", **checker}, "tile_m": tile_m},
        },
        "objects": [
            {"type": "room", "size": [room, room, room], "center": [0, 0, 0], "material": "bg"},
            {
                "type": "plane",
                "center": [0.0, distance, 1.5],
                "size": [size, size],
                "normal": [0, -1, 0],
                "material": "chk",
            },
        ],
        "trajectory": {
            "key_poses": [
                {"position": [0, 0, 1.5], "look_at": [0, 1, 1.5]},
                {"position": [0.1, 0, 1.5], "look_at": [0.1, 1, 1.5]},
            ]
        },
    }
    rconf = {"camera": camera or CAM, **(render or {})}
    return load_scene({"scene": spec}, {"render": rconf})


def test_plane_at_known_depth_renders_that_depth():
    scene = _plane_scene(2.0, {"size": 16, "squares": 2}, 1.0)
    out = Renderer(scene).render(T_FRONT)
    assert out.depth.shape == (48, 64) and out.depth.dtype == np.float32
    np.testing.assert_allclose(out.depth, 2.0, atol=1e-5)  # z-depth, not ray length
    plane_tris = set(np.unique(out.triangle_ids).tolist())
    assert plane_tris <= {12, 13}  # the plane's two triangles (after the room's 12)


def test_depth_with_distortion_is_still_z_depth():
    cam = {**CAM, "k1": -0.25, "k2": 0.05}
    scene = _plane_scene(2.0, {"size": 16, "squares": 2}, 1.0, camera=cam)
    assert scene.camera.has_distortion
    out = Renderer(scene).render(T_FRONT)
    np.testing.assert_allclose(out.depth, 2.0, atol=1e-5)


def test_uv_mapping_matches_analytic_checker():
    # 64-texel checker of 8 squares over 1.6 m: squares of 0.2 m; at 1 m a pixel is 2 cm < 1 texel
    low, high = 0.1, 0.7
    scene = _plane_scene(1.0, {"size": 64, "squares": 8, "low": low, "high": high}, 1.6)
    rad = Renderer(scene).radiance(T_FRONT)
    rays = scene.camera.pixel_rays()
    X = EYE[0] + rays[..., 0] * 1.0  # camera x = world x, camera y = -world z
    Z = EYE[2] - rays[..., 1] * 1.0
    u = X - (0.0 - 4.0)  # metres from the plane's left edge
    v = (1.5 + 4.0) - Z  # metres down from its top edge
    i, j = np.floor(u / 0.2), np.floor(v / 0.2)
    expected = np.where((i + j) % 2 == 1, high, low)
    du = np.minimum(u % 0.2, 0.2 - u % 0.2)
    dv = np.minimum(v % 0.2, 0.2 - v % 0.2)
    away = (du > 0.03) & (dv > 0.03)  # more than a texel (2.5 cm) from a square edge
    assert away.mean() > 0.3
    np.testing.assert_allclose(rad[away], expected[away], rtol=1e-5)


def test_distant_fine_checker_renders_to_its_mean_near_one_keeps_contrast():
    chk = {"size": 256, "squares": 64, "low": 0.1, "high": 0.7}  # 10 cm squares at tile 6.4 m
    near = Renderer(_plane_scene(1.0, chk, 6.4)).radiance(T_FRONT)
    far_scene = _plane_scene(
        37.0, chk, 6.4, room=200.0, size=80.0
    )  # a pixel covers 0.74 m = 7.4 squares
    far = Renderer(far_scene).radiance(T_FRONT)
    assert near.std() / near.mean() > 0.5
    assert far.mean() == pytest.approx(0.4, rel=0.01)
    assert far.std() / far.mean() < 0.01
    # without mip-mapping (a huge negative bias) the same view aliases into strong false contrast
    aliased = Renderer(
        _plane_scene(37.0, chk, 6.4, room=200.0, size=80.0, render={"lod_bias": -30.0})
    ).radiance(T_FRONT)
    assert aliased.std() / aliased.mean() > 0.3


def test_moving_camera_over_fine_texture_does_not_flicker():
    """Sub-pixel motion over a texture finer than a pixel changes the image by far less than the
    texture contrast (what would fire spurious events)."""
    chk = {"size": 256, "squares": 64, "low": 0.1, "high": 0.7}
    scene = _plane_scene(20.0, chk, 6.4)
    r = Renderer(scene)
    a = r.radiance(T_FRONT)
    T = T_FRONT.copy()
    T[0, 3] += 0.13  # 0.33 px at 20 m
    b = r.radiance(T)
    assert np.abs(np.log(b) - np.log(a)).max() < 0.05


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
def test_numba_and_numpy_backends_agree():
    scene = load_scene({"scene": "desk"}, {"render": {"camera": CAM}})
    T = scene.trajectory.pose(1.3)
    a = Renderer(scene, backend="numba").radiance(T)
    b = Renderer(scene, backend="numpy").radiance(T)
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)


def test_supersampling_keeps_shape_depth_and_mean():
    scene = load_scene({"scene": "room"}, {"render": {"camera": CAM}})
    T = scene.trajectory.pose(2.0)
    r1, r2 = Renderer(scene), Renderer(scene, supersample=2)
    o1, o2 = r1.render(T), r2.render(T)
    assert o2.radiance.shape == o1.radiance.shape == (48, 64)
    np.testing.assert_array_equal(o2.depth, o1.depth)
    np.testing.assert_array_equal(o2.triangle_ids, o1.triangle_ids)
    assert o2.radiance.mean() == pytest.approx(o1.radiance.mean(), rel=0.03)
    assert not np.array_equal(o2.radiance, o1.radiance)
    # the configured value is the default
    s2 = load_scene({"scene": "room"}, {"render": {"camera": CAM, "supersample": 2}})
    assert Renderer(s2).supersample == 2


def test_light_and_lit_surfaces_scale_by_dynamic_range():
    conf = {"render": {"camera": CAM}}
    a = load_scene({"scene": "room"}, conf)
    b = load_scene({"scene": "room", "dynamic_range": 1000.0}, conf)
    T = a.trajectory.pose(0.0)
    oa, ob = Renderer(a).render(T), Renderer(b).render(T)
    light = a.tri_light[oa.triangle_ids]
    lit = a.tri_lit[oa.triangle_ids]
    assert light.mean() > 0.02  # the window is in view
    assert lit.mean() > 0.1  # so is the sunlit floor
    bright = light | lit
    np.testing.assert_allclose(ob.radiance[bright], 1000.0 * oa.radiance[bright], rtol=1e-5)
    # everything else keeps its radiance
    np.testing.assert_array_equal(ob.radiance[~bright], oa.radiance[~bright])
    # HDR: the brightest light is >= 10^4 times the darkest surface
    assert ob.radiance.max() / ob.radiance.min() > 1e4


def test_rays_that_miss_give_floor_radiance_zero_depth_and_no_id():
    spec = {
        "materials": {"m": {"texture": {"type": "constant", "value": 0.5}}},
        "objects": [
            {
                "type": "plane",
                "center": [0, 2, 1.5],
                "size": [0.5, 0.5],
                "normal": [0, -1, 0],
                "material": "m",
            }
        ],
        "trajectory": {
            "key_poses": [
                {"position": [0, 0, 1.5], "look_at": [0, 1, 1.5]},
                {"position": [1, 0, 1.5], "look_at": [1, 1, 1.5]},
            ]
        },
    }
    scene = load_scene({"scene": spec}, {"render": {"camera": CAM, "radiance_floor": 1e-4}})
    out = Renderer(scene).render(T_FRONT)
    miss = out.triangle_ids < 0
    assert 0.5 < miss.mean() < 0.99
    assert (out.radiance[miss] == np.float32(1e-4)).all() and (out.depth[miss] == 0).all()
    assert (out.radiance[~miss] > 0.2).all() and np.allclose(out.depth[~miss], 2.0, atol=1e-5)


def test_radiance_at_follows_the_trajectory():
    scene = load_scene({"scene": "facade"}, {"render": {"camera": CAM}})
    r = Renderer(scene)
    np.testing.assert_array_equal(r.radiance_at(1.0), r.radiance(scene.trajectory.pose(1.0)))
    with pytest.raises(ValueError, match="T_wc"):
        r.radiance(np.eye(3))
