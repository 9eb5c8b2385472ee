"""Scenes, presets, trajectories and their validation (evdense.sim.scene / trajectory / textures)."""

from __future__ import annotations

import numpy as np
import pytest

from evdense.sim.presets import PRESETS
from evdense.sim.render import Renderer
from evdense.sim.scene import load_scene
from evdense.sim.textures import (
    TextureAtlas,
    dead_leaves,
    dead_leaves_labels,
    mip_pyramid,
    normalize_texture_spec,
)

# a small camera with the DAVIS346 field of view, to keep renders fast
SMALL = {
    "render": {
        "camera": {"width": 87, "height": 65, "fx": 62.5, "fy": 62.5, "cx": 43.0, "cy": 32.0}
    }
}


def _spec(**over) -> dict:
    spec = {
        "name": "t",
        "duration": 2.0,
        "materials": {
            "m": {"texture": {"type": "checker", "size": 16, "squares": 4}, "tile_m": 1.0}
        },
        "objects": [{"type": "room", "size": [6, 6, 3], "center": [0, 0, 1.5], "material": "m"}],
        "trajectory": {
            "type": "spline",
            "key_poses": [
                {"position": [-1, -1, 1.5], "look_at": [0, 2, 1]},
                {"position": [1, -1, 1.5], "look_at": [0, 2, 1]},
            ],
        },
    }
    spec.update(over)
    return spec


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_is_closed_lit_and_at_a_sensible_distance(name):
    scene = load_scene({"scene": name, "dynamic_range": 1000.0}, SMALL)
    assert scene.tri_light.any(), "every preset has a light surface for HDR"
    assert 3.0 <= scene.trajectory.duration <= 6.0
    r = Renderer(scene)
    medians, light_seen = [], False
    for t in np.linspace(0, scene.trajectory.duration, 6):
        out = r.render(scene.trajectory.pose(t))
        assert (out.triangle_ids >= 0).all(), f"{name}: a ray escaped at t={t}"
        assert (out.depth > 0.3).all()
        assert np.isfinite(out.radiance).all() and (out.radiance > 0).all()
        medians.append(np.median(out.depth))
        light_seen |= bool(scene.tri_light[out.triangle_ids].any())
    assert 1.0 <= np.median(medians) <= 5.0, f"{name}: median depth {np.median(medians):.2f} m"
    assert light_seen, f"{name}: the light surface is never in view"
    # the camera translates (parallax), not only rotates
    p = scene.trajectory.pose(np.array([0.0, scene.trajectory.duration]))[:, :3, 3]
    assert np.linalg.norm(p[1] - p[0]) > 1.0


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_dynamic_range_scales_light_and_lit_surfaces_only(name):
    a = load_scene({"scene": name}, SMALL)
    b = load_scene({"scene": name, "dynamic_range": 1000.0}, SMALL)
    bright = b.tri_light | b.tri_lit
    assert b.tri_lit.any() and not (b.tri_lit & b.tri_light).any()
    np.testing.assert_allclose(b.tri_gain[bright], 1000.0 * a.tri_gain[bright], rtol=1e-6)
    np.testing.assert_array_equal(b.tri_gain[~bright], a.tri_gain[~bright])
    # a lit surface keeps its shading (faces differ), a light has none
    assert np.unique(b.tri_gain[b.tri_lit].round(3)).size > 1 or b.tri_lit.sum() < 3


def test_a_material_is_light_or_lit_not_both():
    mats = {"m": {"texture": {"type": "checker", "size": 16}, "light": True, "lit": True}}
    with pytest.raises(ValueError, match=r"materials\.m: a material is a light or lit"):
        load_scene({"scene": _spec(materials=mats)}, SMALL)


def test_trajectory_speed_and_key_poses():
    spec = _spec()
    s1 = load_scene({"scene": spec}, SMALL)
    s2 = load_scene({"scene": spec, "speed": 2.0}, SMALL)
    assert s1.trajectory.duration == pytest.approx(2.0)
    assert s2.trajectory.duration == pytest.approx(1.0)
    t = np.linspace(0, 1.0, 11)
    np.testing.assert_allclose(s2.trajectory.pose(t), s1.trajectory.pose(2 * t), atol=1e-12)
    # ends pass through the key poses; orientation looks at the key target, z forward, y down
    T0 = s1.trajectory.pose(0.0)
    np.testing.assert_allclose(T0[:3, 3], [-1, -1, 1.5])
    fwd = np.array([0, 2, 1]) - np.array([-1, -1, 1.5])
    np.testing.assert_allclose(T0[:3, 2], fwd / np.linalg.norm(fwd), atol=1e-12)
    assert T0[2, 1] < 0  # camera y (down) points down in the world
    np.testing.assert_allclose(s1.trajectory.pose(2.0)[:3, 3], [1, -1, 1.5])
    # rotation matrices are orthonormal
    R = s1.trajectory.pose(t)[:, :3, :3]
    np.testing.assert_allclose(
        R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )


def test_trajectory_is_smooth():
    scene = load_scene({"scene": "room"}, SMALL)
    t = np.linspace(0, scene.trajectory.duration, 2001)
    p = scene.trajectory.pose(t)[:, :3, 3]
    v = np.diff(p, axis=0) / np.diff(t)[:, None]
    acc = np.diff(v, axis=0) / np.diff(t)[1:, None]
    assert np.abs(np.diff(acc, axis=0)).max() < 0.5  # continuous acceleration: no kinks
    speed = np.linalg.norm(v, axis=1)
    assert 0.2 < speed.min() and speed.max() < 3.0  # metres per second at speed 1


def test_orbit_trajectory():
    traj = {
        "type": "orbit",
        "center": [0, 0, 0],
        "radius": 2.0,
        "height": 1.5,
        "start_deg": -30,
        "end_deg": 30,
    }
    scene = load_scene({"scene": _spec(trajectory=traj)}, SMALL)
    T = scene.trajectory.pose(np.linspace(0, 2, 5))
    np.testing.assert_allclose(np.linalg.norm(T[:, :2, 3], axis=1), 2.0)
    np.testing.assert_allclose(T[:, 2, 3], 1.5)


@pytest.mark.parametrize(
    ("dataset", "key"),
    [
        ({"scene": "no_such_preset"}, "scene"),
        ({"scene": _spec(), "duration": 0}, "duration"),
        ({"scene": _spec(), "speed": 0.0}, "speed"),
        ({"scene": _spec(), "dynamic_range": 0.5}, "dynamic_range"),
        (
            {
                "scene": _spec(
                    trajectory={
                        "type": "spline",
                        "key_poses": [{"position": [0, 0, 1], "look_at": [0, 1, 1]}],
                    }
                )
            },
            "key_poses",
        ),
        ({"scene": _spec(trajectory={"type": "spiral"})}, "trajectory.type"),
        (
            {"scene": _spec(materials={"m": {"texture": "/no/such/texture.png"}})},
            "materials.m.texture.path",
        ),
        (
            {"scene": _spec(materials={"m": {"texture": "skimage:no_such_image"}})},
            "materials.m.texture.path",
        ),
        (
            {"scene": _spec(materials={"m": {"texture": {"type": "wood"}}})},
            "materials.m.texture.type",
        ),
        ({"scene": _spec(objects=[{"type": "sphere", "material": "m"}])}, "objects[0].type"),
        (
            {
                "scene": _spec(
                    objects=[
                        {"type": "box", "size": [1, 1, 1], "center": [0, 0, 0], "material": "x"}
                    ]
                )
            },
            "objects[0].material",
        ),
        (
            {"scene": _spec(objects=[{"type": "mesh", "path": "/no/such.obj", "material": "m"}])},
            "objects[0].path",
        ),
        ({"scene": {"base": "nope"}}, "scene.base"),
        (
            {
                "scene": _spec(
                    objects=[{"type": "plane", "center": [0, 0, 0], "size": [1, 1], "colour": 1}]
                )
            },
            "objects[0].colour",
        ),
        ({"scene": _spec(wibble=1)}, "scene.wibble"),
    ],
)
def test_invalid_scene_names_the_key(dataset, key):
    with pytest.raises(
        ValueError, match=key.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")
    ):
        load_scene(dataset, SMALL)


def test_invalid_render_config_names_the_key():
    with pytest.raises(ValueError, match=r"simulator\.render\.supersample"):
        load_scene({"scene": _spec()}, {"render": {"supersample": 0}})
    with pytest.raises(ValueError, match=r"simulator\.render\.camera"):
        load_scene({"scene": _spec()}, {"render": {"camera": {"width": 10}}})


def test_scene_yaml_file_with_base_and_relative_texture(tmp_path):
    import imageio.v3 as iio

    iio.imwrite(tmp_path / "tex.png", (np.arange(64 * 64).reshape(64, 64) % 251).astype(np.uint8))
    (tmp_path / "s.yaml").write_text(
        "base: room\nduration: 2.5\nmaterials:\n  m: {texture: tex.png, tile_m: 1.0}\n"
        "objects:\n  - {type: room, size: [5, 5, 3], center: [0, 0, 1.5], material: m}\n"
    )
    scene = load_scene({"scene": str(tmp_path / "s.yaml")}, SMALL)
    assert scene.trajectory.duration == pytest.approx(2.5)
    assert scene.spec["materials"]["m"]["texture"]["path"] == str(tmp_path / "tex.png")
    assert scene.textures[0].shape == (64, 64)


def test_distortion_from_config():
    scene = load_scene({"scene": _spec()}, {"render": {"camera": {"k1": -0.2, "k2": 0.05}}})
    assert scene.camera.width == 346 and scene.camera.dist == (-0.2, 0.05, 0.0, 0.0)


def test_imported_meshes_obj_with_uvs_and_ply_without(tmp_path):
    import open3d as o3d

    # a 1 m quad in the x-z plane at y = 1, with UVs spanning the texture once
    (tmp_path / "quad.obj").write_text(
        "v -0.5 1 0.5\nv 0.5 1 0.5\nv 0.5 1 1.5\nv -0.5 1 1.5\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    box = o3d.geometry.TriangleMesh.create_box(0.4, 0.4, 0.4)
    o3d.io.write_triangle_mesh(str(tmp_path / "box.ply"), box)
    objs = _spec()["objects"] + [
        {"type": "mesh", "path": "quad.obj", "material": "m"},
        {
            "type": "mesh",
            "path": str(tmp_path / "box.ply"),
            "material": "m",
            "position": [1, 1, 0],
            "scale": 2.0,
        },
    ]
    spec = _spec(objects=objs)
    (tmp_path / "scene.yaml").write_text(__import__("yaml").safe_dump(spec))
    scene = load_scene({"scene": str(tmp_path / "scene.yaml")}, SMALL)
    n_room = 12
    quad_uv = scene.tri_uv[n_room : n_room + 2]
    assert quad_uv.min() == pytest.approx(0.0) and quad_uv.max() == pytest.approx(
        16.0
    )  # 16-texel texture
    # texels per metre from the UV mapping: 16 texels over 1 m
    np.testing.assert_allclose(2.0 ** scene.tri_log2_tpm[n_room : n_room + 2], 16.0, rtol=1e-5)
    box_v = scene.vertices[scene.triangles[n_room + 2 :]]
    np.testing.assert_allclose(box_v.reshape(-1, 3).max(axis=0), [1.8, 1.8, 0.8])
    # tri-planar UVs for the PLY: the box's metres map at the material's tile size (16 texels / m)
    np.testing.assert_allclose(2.0 ** scene.tri_log2_tpm[n_room + 2 :], 16.0, rtol=1e-5)


def test_textures_tile_and_mip_means():
    spec = normalize_texture_spec(
        {"type": "checker", "size": 64, "squares": 8, "low": 0.2, "high": 0.6}, "t"
    )
    assert spec["type"] == "checker"
    with pytest.raises(ValueError, match=r"t\.size"):
        normalize_texture_spec({"type": "noise", "size": 100}, "t")
    img = dead_leaves(64, 2, 20, 3.0, np.random.default_rng(0))
    assert img.shape == (64, 64) and 0 <= img.min() and img.max() <= 1 and not np.isnan(img).any()
    labels, values = dead_leaves_labels(64, 2, 20, 3.0, np.random.default_rng(0))
    assert labels.min() >= 0 and labels.max() < len(values)  # the torus is covered
    assert np.array_equal(img, values[labels])  # the same draw as the image
    # disks wider than the torus (the planar mosaic's 300 px on 512 texels) wrap onto themselves:
    # the torus is covered all the same, and the generator ends after the 400 batches of 512 disks
    # it has always drawn there, so a seed's later draws (the mosaic's fills) stay as they were
    rng = np.random.default_rng(0)
    labels, values = dead_leaves_labels(32, 2, 40, 3.0, rng)
    assert labels.min() >= 0 and len(values) == 400 * 512
    after = np.random.default_rng(0)
    for _ in range(400):
        after.random(512), after.integers(0, 32, size=(512, 2)), after.random(512)
    assert rng.random() == after.random()
    pyr = mip_pyramid(img)
    assert [p.shape for p in pyr] == [(64 >> k, 64 >> k) for k in range(7)]
    for p in pyr:
        assert p.mean() == pytest.approx(img.mean(), rel=1e-5)
    atlas = TextureAtlas.build([img, np.ones((4, 8), np.float32)])
    assert atlas.num_levels.tolist() == [7, 4]
    assert atlas.texels.size == sum(p.size for p in pyr) + 32 + 8 + 2 + 1
