"""Writing and reading a textured mesh: OBJ + MTL + PNG, vertex-coloured PLY, GLB."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d

from evdense.formats.files import atomic_path
from evdense.mesh.views import write_png
from evdense.texture.model import TexturedMesh


# --- export -----------------------------------------------------------------------------------
def write_textured_mesh(
    folder: str | Path, tm: TexturedMesh, name: str = "mesh"
) -> dict[str, Path]:
    """Write ``<name>.obj``, ``<name>.mtl``, ``<name>_texture.png``, ``<name>_colored.ply`` and
    ``<name>.glb`` in ``folder``.

    The OBJ has one texture coordinate per face corner; it opens in MeshLab, Blender and open3d.
    The GLB (binary glTF, texture embedded) opens in Blender, web viewers and open3d.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    png = folder / f"{name}_texture.png"
    mtl = folder / f"{name}.mtl"
    obj = folder / f"{name}.obj"
    ply = folder / f"{name}_colored.ply"
    write_png(png, tm.atlas)
    mtl.write_text(
        "# evdense texture\nnewmtl material_0\nKa 1.0 1.0 1.0\nKd 1.0 1.0 1.0\nKs 0.0 0.0 0.0\n"
        f"d 1.0\nillum 1\nmap_Kd {png.name}\n"
    )
    F = len(tm.faces)
    vt = tm.face_uvs.reshape(-1, 2)
    fv = tm.faces + 1
    ft = np.arange(1, 3 * F + 1).reshape(F, 3)
    with open(obj, "w") as fh:
        fh.write(
            f"# evdense textured mesh: {len(tm.vertices)} vertices, {F} faces\nmtllib {mtl.name}\n"
        )
        np.savetxt(fh, tm.vertices, fmt="v %.7g %.7g %.7g")
        np.savetxt(fh, vt, fmt="vt %.7f %.7f")
        fh.write("usemtl material_0\n")
        np.savetxt(
            fh,
            np.stack([fv[:, 0], ft[:, 0], fv[:, 1], ft[:, 1], fv[:, 2], ft[:, 2]], axis=1),
            fmt="f %d/%d %d/%d %d/%d",
        )
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(tm.vertices),
        o3d.utility.Vector3iVector(tm.faces.astype(np.int32)),
    )
    if tm.vertex_colors is not None:
        mesh.vertex_colors = o3d.utility.Vector3dVector(tm.vertex_colors)
    mesh.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(ply), mesh)
    glb = write_glb(folder / f"{name}.glb", tm)
    return {"obj": obj, "mtl": mtl, "texture": png, "ply": ply, "glb": glb}


def write_glb(path: str | Path, tm: TexturedMesh) -> Path:
    """Write a binary glTF 2.0 file: one textured primitive (corners unshared, texture embedded
    as PNG, unlit-looking material: no metal, full roughness). Coordinates stay in the world frame
    (glTF viewers assume y up)."""
    import struct

    import imageio.v3 as iio

    path = Path(path)
    F = len(tm.faces)
    pos = tm.vertices[tm.faces].reshape(-1, 3).astype(np.float32)
    uv = tm.face_uvs.reshape(-1, 2).astype(np.float32).copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # glTF texture coordinates start at the top-left
    idx = np.arange(3 * F, dtype=np.uint32)
    img = np.clip(np.rint(tm.atlas * 255), 0, 255).astype(np.uint8)
    png = iio.imwrite("<bytes>", img[..., 0] if img.shape[2] == 1 else img, extension=".png")
    blobs, views = [], []
    offset = 0
    for data, target in (
        (pos.tobytes(), 34962),
        (uv.tobytes(), 34962),
        (idx.tobytes(), 34963),
        (png, None),
    ):
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target:
            view["target"] = target
        views.append(view)
        pad = (-len(data)) % 4
        blobs.append(data + b"\0" * pad)
        offset += len(data) + pad
    gltf = {
        "asset": {"version": "2.0", "generator": "evdense"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [
            {
                "primitives": [
                    {"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}
                ]
            }
        ],
        "materials": [
            {
                "pbrMetallicRoughness": {
                    "baseColorTexture": {"index": 0},
                    "metallicFactor": 0.0,
                    "roughnessFactor": 1.0,
                },
                "doubleSided": True,
            }
        ],
        "textures": [{"source": 0, "sampler": 0}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987}],
        "images": [{"bufferView": 3, "mimeType": "image/png"}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3 * F,
                "type": "VEC3",
                "min": pos.min(0).tolist(),
                "max": pos.max(0).tolist(),
            },
            {"bufferView": 1, "componentType": 5126, "count": 3 * F, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5125, "count": 3 * F, "type": "SCALAR"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": offset}],
    }
    js = json.dumps(gltf, separators=(",", ":")).encode()
    js += b" " * ((-len(js)) % 4)
    binary = b"".join(blobs)
    total = 12 + 8 + len(js) + 8 + len(binary)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(struct.pack("<III", 0x46546C67, 2, total))
        fh.write(struct.pack("<II", len(js), 0x4E4F534A) + js)
        fh.write(struct.pack("<II", len(binary), 0x004E4942) + binary)
    return path


def read_textured_mesh(obj_path: str | Path) -> TexturedMesh:
    """Read an OBJ with one material and ``map_Kd`` texture (as written by :func:`write_textured_mesh`;
    triangles only, ``f v/vt`` or ``f v/vt/vn``)."""
    from evdense.mesh.views import read_image

    obj_path = Path(obj_path)
    if not obj_path.is_file():
        raise ValueError(f"{obj_path}: OBJ file not found")
    verts, uvs, fv, ft, mtllib = [], [], [], [], None
    for line in obj_path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            uvs.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            if len(parts) != 4:
                raise ValueError(f"{obj_path}: only triangles are supported ({line!r})")
            idx = [p.split("/") for p in parts[1:]]
            fv.append([int(i[0]) - 1 for i in idx])
            ft.append([int(i[1]) - 1 if len(i) > 1 and i[1] else -1 for i in idx])
        elif parts[0] == "mtllib":
            mtllib = obj_path.parent / parts[1]
    if mtllib is None or not mtllib.is_file():
        raise ValueError(f"{obj_path}: no material library")
    tex_name = next(
        (
            ln.split(maxsplit=1)[1].strip()
            for ln in mtllib.read_text().splitlines()
            if ln.startswith("map_Kd")
        ),
        None,
    )
    if tex_name is None:
        raise ValueError(f"{mtllib}: no map_Kd texture")
    atlas = read_image(mtllib.parent / tex_name)
    if atlas.ndim == 2:
        atlas = atlas[..., None]
    uv = np.asarray(uvs)
    ft_a = np.asarray(ft)
    if (ft_a < 0).any():
        raise ValueError(f"{obj_path}: faces without texture coordinates")
    return TexturedMesh(np.asarray(verts), np.asarray(fv, dtype=np.int64), uv[ft_a], atlas)
