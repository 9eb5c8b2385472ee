"""Static textured scenes: geometry (planes, boxes, cylinders, imported meshes), materials (texture,
radiance, light sources), the camera and its trajectory.

A scene spec is a YAML-friendly dict (see :mod:`evdense.sim.presets` for the shipped ones)::

    name: room
    duration: 4.0                      # seconds of the path at speed 1
    shading: {direction: [0.3, -0.5, 1.0], ambient: 0.55}
    materials:
      wall: {texture: {type: dead_leaves}, tile_m: 2.0, radiance: 1.0}
      lamp: {texture: {type: noise}, tile_m: 0.5, radiance: 2.0, light: true}
    objects:
      - {type: room, size: [6, 5, 3], center: [0, 0, 1.5], material: wall,
         face_materials: {floor: floor, ceiling: ceiling}}
      - {type: box, size: [1, 1, 1], center: [0, 1, 0.5], rotation_deg: [0, 0, 20], material: crate}
      - {type: plane, center: [0, 2.49, 1.6], size: [1.2, 0.8], normal: [0, -1, 0], material: lamp}
      - {type: cylinder, center: [0, 0, 0], radius: 0.3, height: 0.5, material: crate}
      - {type: mesh, path: bunny.obj, scale: 1.0, position: [0, 0, 0], rotation_deg: [0, 0, 0],
         material: crate}
    trajectory: {type: spline, key_poses: [{position: [...], look_at: [...]}, ...]}
    base: room                         # optional: start from a preset and override top-level keys

Boxes and rooms take ``face_materials`` per face (``left`` -x, ``right`` +x, ``front`` -y, ``back``
+y, ``bottom`` -z, ``top`` +z; rooms also ``floor``, ``ceiling``, ``walls``) and ``open_faces`` (faces
left out, e.g. the bottom of a box standing on the floor). ``rotation_deg`` is an extrinsic x-y-z
Euler rotation about the object's centre (the mesh's origin). Planes take ``normal`` (the side seen)
and optional ``up``. Paths (textures, meshes) are relative to the scene YAML's folder.

Radiance is linear and relative: an ordinary surface has radiance ``reflectance * radiance * shading``
(shading = ``ambient + (1 - ambient) * |n . direction|``, a fixed soft key light so that faces differ);
a light surface (``light: true``) has ``reflectance * radiance * dynamic_range`` and no shading;
a lit surface (``lit: true``: the floor in the sunlight from a window, the desk under its lamp) has
the ordinary radiance times ``dynamic_range``. Lights alone make an HDR scene whose bright part is
a few small patches, which a metering camera simply lets saturate; lit surfaces put a large part of
every view that many times above the rest, which no 8-bit exposure holds at once.
"""

from __future__ import annotations

import copy
import json
import numbers
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from evdense.camera import Camera
from evdense.log import get_logger
from evdense.sim.presets import PRESETS
from evdense.sim.render import RenderConfig
from evdense.sim.textures import make_texture, normalize_texture_spec, texture_seed
from evdense.sim.trajectory import Trajectory, _vec3, make_trajectory

log = get_logger("sim.scene")

OBJECT_TYPES = ("room", "box", "plane", "cylinder", "mesh")
BOX_FACES = {  # face name -> (axis, sign): outward direction of the face
    "right": (0, 1),
    "left": (0, -1),
    "back": (1, 1),
    "front": (1, -1),
    "top": (2, 1),
    "bottom": (2, -1),
}
ROOM_FACE_ALIASES = {"ceiling": "top", "floor": "bottom"}
_BOX_KEYS = {"type", "size", "center", "rotation_deg", "material", "face_materials", "open_faces"}
OBJECT_KEYS = {
    "room": _BOX_KEYS,
    "box": _BOX_KEYS,
    "plane": {"type", "center", "size", "normal", "up", "material"},
    "cylinder": {"type", "center", "radius", "height", "segments", "rotation_deg", "material"},
    "mesh": {"type", "path", "scale", "position", "rotation_deg", "material"},
}
DATASET_DEFAULTS = {"speed": 1.0, "dynamic_range": 1.0, "seed": 0}


@dataclass
class Material:
    """One surface material: a texture, its physical tile size and its radiance."""

    name: str
    texture: dict
    """Normalised texture spec (see :mod:`evdense.sim.textures`)."""
    tile_m: float
    """Width of one texture tile on the surface, metres."""
    radiance: float
    """Radiance multiplier (relative units; ordinary surfaces ~1)."""
    light: bool
    """True for light sources (lamps, windows): radiance times the dataset's dynamic_range, unshaded."""
    lit: bool = False
    """True for surfaces in the light's beam (sunlit floor, the desk under the lamp): shaded radiance
    times the dataset's dynamic_range."""


@dataclass
class Scene:
    """A static scene ready to render: triangle mesh with per-triangle texture data, camera, path.

    Per-triangle arrays (``T`` triangles): ``tri_uv`` ``(T, 3, 2)`` float32 level-0 texel coordinates
    of the three corners; ``tri_texture`` ``(T,)`` int32 index into ``textures``; ``tri_log2_tpm``
    ``(T,)`` float32 log2 of texels per metre; ``tri_gain`` ``(T,)`` float32 radiance multiplier;
    ``tri_normal`` ``(T, 3)`` unit normals; ``tri_light`` ``(T,)`` bool light-source mask.
    """

    name: str
    camera: Camera
    trajectory: Trajectory
    vertices: np.ndarray
    """``(V, 3)`` float64 world coordinates, metres."""
    triangles: np.ndarray
    """``(T, 3)`` int64 vertex indices."""
    tri_uv: np.ndarray
    tri_texture: np.ndarray
    tri_log2_tpm: np.ndarray
    tri_gain: np.ndarray
    tri_normal: np.ndarray
    tri_light: np.ndarray
    tri_lit: np.ndarray
    """``(T,)`` bool mask of lit surfaces (radiance times ``dynamic_range``, shaded)."""
    textures: list[np.ndarray]
    """Reflectance textures ``(h, w)`` float32, power-of-two sides."""
    materials: list[Material]
    render: RenderConfig
    dataset: dict
    """Resolved dataset parameters: speed, dynamic_range, duration (s at speed 1), seed."""
    spec: dict = field(repr=False)
    """The resolved scene spec (defaults filled, file paths absolute)."""

    def to_o3d(self):
        """The scene geometry as an ``open3d.geometry.TriangleMesh`` (world frame, metres)."""
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices),
            o3d.utility.Vector3iVector(self.triangles.astype(np.int32)),
        )
        mesh.compute_vertex_normals()
        return mesh

    def write_mesh(self, path: str | Path) -> None:
        """Write the world-frame mesh as PLY (vertex colours = mean reflectance of the texture)."""
        import open3d as o3d

        mesh = self.to_o3d()
        grey = np.zeros(len(self.vertices))
        means = np.array([float(t.mean()) for t in self.textures])
        grey[self.triangles.ravel()] = np.repeat(means[self.tri_texture], 3)
        mesh.vertex_colors = o3d.utility.Vector3dVector(np.repeat(grey[:, None], 3, axis=1))
        if not o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=False):
            raise OSError(f"{path}: could not write mesh")

    def resolved(self) -> dict:
        """JSON-ready description from which :func:`scene_from_resolved` rebuilds this scene."""
        return {"scene": self.spec, "dataset": self.dataset, "render": asdict(self.render)}


# --------------------------------------------------------------------------------------------
# loading


def load_scene(dataset_conf: dict, sim_conf: dict | None = None) -> Scene:
    """Build the scene of one dataset.

    ``dataset_conf``: one entry of ``config["datasets"]`` (keys ``scene`` = preset name, path to a
    scene YAML, or an inline spec dict; ``speed``; ``dynamic_range``; ``duration`` in seconds at
    speed 1, default from the scene; ``seed``). ``sim_conf``: ``config["simulator"]`` (only its
    ``render`` section is read here). Raises ``ValueError`` naming the offending key.
    """
    if not isinstance(dataset_conf, dict):
        raise ValueError(f"dataset: expected a mapping, got {dataset_conf!r}")
    if "scene" not in dataset_conf:
        raise ValueError("scene: a synthetic dataset needs a `scene` (preset name or scene YAML)")
    if "recording" in dataset_conf:
        raise ValueError("recording: give `scene` or `recording`, not both")
    spec, base_dir = resolve_scene_spec(dataset_conf["scene"])
    dataset = {**DATASET_DEFAULTS, "duration": spec.get("duration", 4.0)}
    for k in ("speed", "dynamic_range", "duration", "seed"):
        if dataset_conf.get(k) is not None:
            dataset[k] = dataset_conf[k]
    _check_number("speed", dataset["speed"], lo=0.0)
    _check_number("dynamic_range", dataset["dynamic_range"], lo=1.0, inclusive=True)
    _check_number("duration", dataset["duration"], lo=0.0)
    if isinstance(dataset["seed"], bool) or not isinstance(dataset["seed"], numbers.Integral):
        raise ValueError(f"seed: must be an integer, got {dataset['seed']!r}")
    # plain Python numbers (Snakemake's Paramspace hands numpy scalars), JSON-ready for scene.json
    dataset = {k: (int(v) if k == "seed" else float(v)) for k, v in dataset.items()}
    render = RenderConfig.from_dict((sim_conf or {}).get("render") or {})
    return build_scene(spec, dataset, render, base_dir)


def scene_from_resolved(resolved: dict | str | Path) -> Scene:
    """Rebuild a scene from :meth:`Scene.resolved` (a dict, or a ``scene.json`` path)."""
    if not isinstance(resolved, dict):
        path = Path(resolved)
        try:
            resolved = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: cannot read resolved scene ({exc})") from exc
    return build_scene(
        resolved["scene"], resolved["dataset"], RenderConfig.from_dict(resolved["render"]), None
    )


def resolve_scene_spec(scene: str | dict) -> tuple[dict, Path | None]:
    """Turn the dataset's ``scene`` value into a spec dict (deep copy) and its base folder."""
    base_dir = None
    if isinstance(scene, dict):
        spec = copy.deepcopy(scene)
    elif isinstance(scene, str):
        if scene in PRESETS:
            spec = copy.deepcopy(PRESETS[scene])
        else:
            path = Path(scene).expanduser()
            if not path.is_file():
                raise ValueError(
                    f"scene: unknown preset {scene!r} (known: {', '.join(sorted(PRESETS))}) and no such file"
                )
            try:
                spec = yaml.safe_load(path.read_text())
            except yaml.YAMLError as exc:
                raise ValueError(f"scene: {path}: invalid YAML ({exc})") from exc
            if not isinstance(spec, dict):
                raise ValueError(f"scene: {path}: expected a mapping at the top level")
            base_dir = path.resolve().parent
    else:
        raise ValueError(f"scene: expected a preset name, a YAML path or a mapping, got {scene!r}")
    if "base" in spec:
        base = spec.pop("base")
        if base not in PRESETS:
            raise ValueError(
                f"scene.base: unknown preset {base!r} (known: {', '.join(sorted(PRESETS))})"
            )
        spec = {**copy.deepcopy(PRESETS[base]), **spec}
    return spec, base_dir


def _check_number(key: str, v, lo: float, inclusive: bool = False) -> None:
    ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and np.isfinite(v)
    ok = ok and (v >= lo if inclusive else v > lo)
    if not ok:
        raise ValueError(f"{key}: must be a number {'>=' if inclusive else '>'} {lo:g}, got {v!r}")


# --------------------------------------------------------------------------------------------
# building


@dataclass
class _Part:
    vertices: np.ndarray  # (n, 3)
    triangles: np.ndarray  # (m, 3)
    uv: (
        np.ndarray
    )  # (m, 3, 2): metres on the surface ("metre") or normalised texture coords ("tile")
    material: list[str]  # per triangle
    uv_unit: str = "metre"


# Over 80 lines on purpose: validation of a scene spec key by key, each with its own message
# naming the key, then the build; read top to bottom it is the spec's documentation.
def build_scene(spec: dict, dataset: dict, render: RenderConfig, base_dir: Path | None) -> Scene:
    """Validate a scene spec and build the :class:`Scene` (see module docstring for the format)."""
    allowed = {"name", "duration", "shading", "materials", "objects", "trajectory", "description"}
    for k in spec:
        if k not in allowed:
            raise ValueError(f"scene.{k}: unknown key (known: {sorted(allowed)})")
    name = str(spec.get("name", "scene"))
    materials = _parse_materials(spec.get("materials"), base_dir)
    shading = {"direction": [0.3, -0.5, 1.0], "ambient": 0.55, **(spec.get("shading") or {})}
    light_dir = _vec3(shading["direction"], "shading.direction")
    light_dir /= np.linalg.norm(light_dir)
    ambient = float(shading["ambient"])
    if not 0 <= ambient <= 1:
        raise ValueError(f"shading.ambient: must be in [0, 1], got {ambient}")

    objects = spec.get("objects")
    if not isinstance(objects, list) or not objects:
        raise ValueError("objects: need a non-empty list of objects")
    parts = [_build_object(o, i, materials, base_dir) for i, o in enumerate(objects)]

    trajectory = make_trajectory(spec.get("trajectory"), dataset["duration"], dataset["speed"])

    # textures: one per material (seeded by dataset seed and material name)
    mat_names = list(materials)
    textures = [
        make_texture(materials[m].texture, texture_seed(dataset["seed"], m)) for m in mat_names
    ]

    verts, tris, tri_uv, tri_mat, tri_tpm = [], [], [], [], []
    offset = 0
    for part in parts:
        verts.append(part.vertices)
        tris.append(part.triangles + offset)
        offset += len(part.vertices)
        mids = np.array([mat_names.index(m) for m in part.material], np.int32)
        tri_mat.append(mids)
        tex_w = np.array([textures[k].shape[1] for k in mids], np.float64)
        tex_h = np.array([textures[k].shape[0] for k in mids], np.float64)
        world = part.vertices[part.triangles]
        if part.uv_unit == "metre":
            tpm = tex_w / np.array([materials[m].tile_m for m in part.material])
            texel = part.uv * tpm[:, None, None]
        else:  # normalised [0, 1] coordinates with v up (OBJ convention)
            texel = np.stack(
                [part.uv[..., 0] * tex_w[:, None], (1.0 - part.uv[..., 1]) * tex_h[:, None]], -1
            )
            d1, d2 = texel[:, 1] - texel[:, 0], texel[:, 2] - texel[:, 0]
            a_tex = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
            a_world = 0.5 * np.linalg.norm(
                np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0]), axis=1
            )
            tpm = np.sqrt(np.maximum(a_tex, 1e-12) / np.maximum(a_world, 1e-12))
        tri_uv.append(texel)
        tri_tpm.append(tpm)
    vertices = np.concatenate(verts).astype(np.float64)
    triangles = np.concatenate(tris).astype(np.int64)
    tri_texture = np.concatenate(tri_mat)
    e = vertices[triangles]
    normal = np.cross(e[:, 1] - e[:, 0], e[:, 2] - e[:, 0])
    area2 = np.linalg.norm(normal, axis=1)
    if np.any(area2 < 1e-12):
        raise ValueError(f"scene {name!r}: {int(np.sum(area2 < 1e-12))} degenerate triangles")
    normal /= area2[:, None]
    is_light = np.array([materials[mat_names[k]].light for k in tri_texture], bool)
    base_rad = np.array([materials[mat_names[k]].radiance for k in tri_texture])
    shade = ambient + (1.0 - ambient) * np.abs(normal @ light_dir)
    is_lit = np.array([materials[mat_names[k]].lit for k in tri_texture], bool)
    dr = float(dataset["dynamic_range"])
    gain = np.where(is_light, base_rad * dr, base_rad * shade * np.where(is_lit, dr, 1.0))

    resolved_spec = {
        "name": name,
        "description": str(spec.get("description", "")),
        "duration": float(spec.get("duration", dataset["duration"])),
        "shading": {"direction": [float(v) for v in shading["direction"]], "ambient": ambient},
        "materials": {m: asdict(materials[m]) for m in mat_names},
        "objects": [_resolved_object(o, base_dir) for o in objects],
        "trajectory": spec["trajectory"],
    }
    for m in resolved_spec["materials"].values():
        m.pop("name")
    scene = Scene(
        name=name,
        camera=render.make_camera(),
        trajectory=trajectory,
        vertices=vertices,
        triangles=triangles,
        tri_uv=np.concatenate(tri_uv).astype(np.float32),
        tri_texture=tri_texture,
        tri_log2_tpm=np.log2(np.concatenate(tri_tpm)).astype(np.float32),
        tri_gain=gain.astype(np.float32),
        tri_normal=normal.astype(np.float32),
        tri_light=is_light,
        tri_lit=is_lit,
        textures=textures,
        materials=[materials[m] for m in mat_names],
        render=render,
        dataset={k: dataset[k] for k in ("speed", "dynamic_range", "duration", "seed")},
        spec=json.loads(json.dumps(resolved_spec)),
    )
    log.debug("scene %s: %d triangles, %d materials", name, len(triangles), len(mat_names))
    return scene


def _parse_materials(mats, base_dir: Path | None) -> dict[str, Material]:
    if not isinstance(mats, dict) or not mats:
        raise ValueError(
            "materials: need a mapping of material names to {texture, tile_m, radiance, light, lit}"
        )
    out = {}
    for name, m in mats.items():
        key = f"materials.{name}"
        if not isinstance(m, dict):
            raise ValueError(f"{key}: expected a mapping, got {m!r}")
        allowed = {"texture", "tile_m", "radiance", "light", "lit"}
        for k in m:
            if k not in allowed:
                raise ValueError(f"{key}.{k}: unknown key (known: {sorted(allowed)})")
        if "texture" not in m:
            raise ValueError(f"{key}.texture: missing")
        tex = normalize_texture_spec(m["texture"], f"{key}.texture", base_dir)
        tile = m.get("tile_m", 1.0)
        _check_number(f"{key}.tile_m", tile, lo=0.0)
        rad = m.get("radiance", 1.0)
        _check_number(f"{key}.radiance", rad, lo=0.0)
        light, lit = bool(m.get("light", False)), bool(m.get("lit", False))
        if light and lit:
            raise ValueError(f"{key}: a material is a light or lit by one, not both")
        out[name] = Material(name, tex, float(tile), float(rad), light, lit)
    return out


def _resolved_object(o: dict, base_dir: Path | None) -> dict:
    o = copy.deepcopy(o)
    if o.get("type") == "mesh" and "path" in o:
        p = Path(o["path"]).expanduser()
        o["path"] = str((base_dir / p if base_dir and not p.is_absolute() else p).resolve())
    return o


def _material_of(o: dict, key: str, materials: dict, face: str | None = None) -> str:
    name = (o.get("face_materials") or {}).get(face) if face else None
    name = name or o.get("material")
    if name is None:
        raise ValueError(f"{key}.material: missing")
    if name not in materials:
        raise ValueError(
            f"{key}.material: unknown material {name!r} (known: {', '.join(materials)})"
        )
    return name


def _size(v, n: int, key: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64) if isinstance(v, list | tuple) else None
    if a is None or a.shape != (n,) or not np.all(a > 0):
        raise ValueError(f"{key}: expected {n} positive numbers, got {v!r}")
    return a


def _rotation(o: dict, key: str) -> np.ndarray:
    r = o.get("rotation_deg", [0.0, 0.0, 0.0])
    return Rotation.from_euler("xyz", _vec3(r, f"{key}.rotation_deg"), degrees=True).as_matrix()


def quad(
    center, right, down, half_w: float, half_h: float, normal
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rectangle as 2 triangles: vertices ``(4, 3)``, triangles ``(2, 3)`` wound so that their normal
    is ``normal``, and corner UVs ``(2, 3, 2)`` in metres (u along ``right``, v along ``down``)."""
    center, right, down = (np.asarray(v, np.float64) for v in (center, right, down))
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64)
    verts = center + corners[:, :1] * half_w * right + corners[:, 1:] * half_h * down
    uv = np.stack([(corners[:, 0] + 1) * half_w, (corners[:, 1] + 1) * half_h], -1)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    n = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    if np.dot(n, normal) < 0:
        tris = tris[:, ::-1]
    return verts, tris, uv[tris]


def _plane_axes(normal: np.ndarray, up: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Right and down axes of a rectangle seen from the side its ``normal`` points to."""
    n = normal / np.linalg.norm(normal)
    if up is None:
        up = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(up, n)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("plane: `up` is parallel to `normal`")
    right /= np.linalg.norm(right)
    down = np.cross(right, n)  # camera convention: x right, y down, z = -normal forward
    return right, down


def _box(o: dict, key: str, materials: dict, inside: bool) -> _Part:
    size = _size(o.get("size"), 3, f"{key}.size")
    center = _vec3(o.get("center"), f"{key}.center")
    R = _rotation(o, key)
    valid = set(BOX_FACES) | ({"floor", "ceiling", "walls"} if inside else set())
    fm = dict(o.get("face_materials") or {})
    for f in fm:
        if f not in valid:
            raise ValueError(f"{key}.face_materials.{f}: unknown face (known: {sorted(valid)})")
    fm = {ROOM_FACE_ALIASES.get(f, f): m for f, m in fm.items()}
    skip = set(o.get("open_faces") or [])
    for f in skip - set(BOX_FACES):
        raise ValueError(f"{key}.open_faces: unknown face {f!r} (known: {sorted(BOX_FACES)})")
    verts, tris, uvs, mats = [], [], [], []
    for face, (axis, sign) in BOX_FACES.items():
        if face in skip:
            continue
        d = np.zeros(3)
        d[axis] = sign
        view_n = -d if inside else d
        right, down = _plane_axes(view_n, None)
        hw = 0.5 * size[int(np.argmax(np.abs(right)))]
        hh = 0.5 * size[int(np.argmax(np.abs(down)))]
        v, t, uv = quad(d * 0.5 * size, right, down, hw, hh, view_n)
        tris.append(t + 4 * len(verts))
        verts.append(v)
        uvs.append(uv)
        mname = fm.get(face) or (fm.get("walls") if axis != 2 else None)
        mkey = f"{key}.face_materials.{face}" if mname else key
        mats += [_material_of({"material": mname or o.get("material")}, mkey, materials)] * 2
    v = np.concatenate(verts) @ R.T + center
    return _Part(v, np.concatenate(tris), np.concatenate(uvs), mats)


def _plane(o: dict, key: str, materials: dict) -> _Part:
    center = _vec3(o.get("center"), f"{key}.center")
    w, h = _size(o.get("size"), 2, f"{key}.size")
    normal = _vec3(o.get("normal", [0, 0, 1]), f"{key}.normal")
    up = _vec3(o["up"], f"{key}.up") if "up" in o else None
    right, down = _plane_axes(normal, up)
    v, t, uv = quad(center, right, down, w / 2, h / 2, normal)
    return _Part(v, t, uv, [_material_of(o, key, materials)] * 2)


def _cylinder(o: dict, key: str, materials: dict) -> _Part:
    """Vertical cylinder standing on ``center`` (base centre); sides UV-mapped by arc length."""
    base = _vec3(o.get("center"), f"{key}.center")
    r = float(o.get("radius", 0))
    h = float(o.get("height", 0))
    if not (r > 0 and h > 0):
        raise ValueError(f"{key}: radius and height must be > 0")
    n = int(o.get("segments", 48))
    R = _rotation(o, key)
    a = np.linspace(0, 2 * np.pi, n + 1)
    ring = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(a)], -1)
    verts = np.concatenate([ring, ring + [0, 0, h], [[0, 0, 0], [0, 0, h]]])
    tris, uvs = [], []
    arc = r * a
    for i in range(n):
        b0, b1, t0, t1 = i, i + 1, n + 1 + i, n + 2 + i
        tris += [
            [b0, b1, t1],
            [b0, t1, t0],
        ]  # outward winding (counter-clockwise seen from outside)
        uvs += [
            [[arc[i], h], [arc[i + 1], h], [arc[i + 1], 0]],
            [[arc[i], h], [arc[i + 1], 0], [arc[i], 0]],
        ]
        cb, ct = 2 * n + 2, 2 * n + 3
        tris += [[cb, b1, b0], [ct, t0, t1]]
        for c, p, q in ((cb, b1, b0), (ct, t0, t1)):
            uvs.append([verts[c][:2] + r, verts[p][:2] + r, verts[q][:2] + r])
    verts = verts @ R.T + base
    return _Part(
        verts,
        np.array(tris),
        np.array(uvs, np.float64),
        [_material_of(o, key, materials)] * len(tris),
    )


def _mesh(o: dict, key: str, materials: dict, base_dir: Path | None) -> _Part:
    """An OBJ/PLY mesh: its own UVs when the file has them (0..1, one texture tile), else a
    tri-planar projection in metres."""
    import open3d as o3d

    p = o.get("path")
    if not isinstance(p, str):
        raise ValueError(f"{key}.path: missing mesh file path")
    path = Path(p).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    if not path.is_file():
        raise ValueError(f"{key}.path: mesh file not found: {path}")
    mesh = o3d.io.read_triangle_mesh(str(path), enable_post_processing=False)
    v = np.asarray(mesh.vertices, np.float64)
    t = np.asarray(mesh.triangles, np.int64)
    if len(t) == 0:
        raise ValueError(f"{key}.path: {path} holds no triangles")
    scale = float(o.get("scale", 1.0))
    R = _rotation(o, key)
    v = (v * scale) @ R.T + _vec3(o.get("position", [0, 0, 0]), f"{key}.position")
    mat = [_material_of(o, key, materials)] * len(t)
    if mesh.has_triangle_uvs() and len(mesh.triangle_uvs) == 3 * len(t):
        uv = np.asarray(mesh.triangle_uvs, np.float64).reshape(-1, 3, 2)
        return _Part(v, t, uv, mat, uv_unit="tile")
    w = v[t]
    n = np.abs(np.cross(w[:, 1] - w[:, 0], w[:, 2] - w[:, 0]))
    axis = np.argmax(n, axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # drop the dominant normal axis
    uv = np.take_along_axis(w, keep[:, None, :].repeat(3, axis=1), axis=2)
    return _Part(v, t, uv, mat)


def _build_object(o, i: int, materials: dict, base_dir: Path | None) -> _Part:
    key = f"objects[{i}]"
    if not isinstance(o, dict):
        raise ValueError(f"{key}: expected a mapping, got {o!r}")
    kind = o.get("type")
    if kind in OBJECT_KEYS:
        for k in o:
            if k not in OBJECT_KEYS[kind]:
                raise ValueError(
                    f"{key}.{k}: unknown key for a {kind} (known: {sorted(OBJECT_KEYS[kind])})"
                )
    if kind == "room":
        return _box(o, key, materials, inside=True)
    if kind == "box":
        return _box(o, key, materials, inside=False)
    if kind == "plane":
        return _plane(o, key, materials)
    if kind == "cylinder":
        return _cylinder(o, key, materials)
    if kind == "mesh":
        return _mesh(o, key, materials, base_dir)
    raise ValueError(f"{key}.type: unknown object type {kind!r} (known: {', '.join(OBJECT_TYPES)})")
