"""Still images of a mesh or a cloud from a camera, for figures and evaluation.

Meshes are ray-cast with open3d: shaded (Lambert with a light at the camera, on face normals),
vertex-coloured (barycentric interpolation) or textured (barycentric UV lookup in the atlas).
Clouds are splatted as squares with a z-buffer.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from evdense.camera import Camera
from evdense.mesh.geometry import camera_rays, cast_rays, make_scene, project, raycast_view
from evdense.texture import TexturedMesh

SHADINGS = ("lambert", "normals", "vertex_colors", "depth")


def _arrays(mesh: o3d.geometry.TriangleMesh | TexturedMesh) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(mesh, TexturedMesh):
        return mesh.vertices, mesh.faces
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def render_mesh(
    mesh: o3d.geometry.TriangleMesh,
    camera: Camera,
    T_wc: np.ndarray,
    shading: str = "lambert",
    background: float = 0.0,
    ambient: float = 0.15,
) -> np.ndarray:
    """Render ``mesh`` from ``camera`` at pose ``T_wc``: ``(H, W, 3)`` float32 in [0, 1]
    (``(H, W)`` z-depth in metres, inf on a miss, for ``shading='depth'``).

    ``shading``: ``lambert`` (grey, ``ambient + (1 - ambient) |n . view|``), ``normals`` (world
    normals mapped to RGB), ``vertex_colors`` (needs vertex colours) or ``depth``.
    """
    if shading not in SHADINGS:
        raise ValueError(f"unknown shading {shading!r}; expected one of {SHADINGS}")
    v, f = _arrays(mesh)
    hits = raycast_view(make_scene(v, f), camera, T_wc)
    if shading == "depth":
        return hits.depth.astype(np.float32)
    H, W = hits.face.shape
    img = np.full((H, W, 3), background, dtype=np.float32)
    m = hits.mask
    if shading == "lambert":
        _, d = camera_rays(camera, T_wc)
        d = d[m] / np.linalg.norm(d[m], axis=1, keepdims=True)
        lam = np.abs(np.einsum("ij,ij->i", hits.normal[m], d))
        img[m] = (ambient + (1 - ambient) * lam)[:, None]
    elif shading == "normals":
        img[m] = 0.5 * (hits.normal[m] + 1.0)
    else:
        if not mesh.has_vertex_colors():
            raise ValueError(
                "render_mesh: shading='vertex_colors' needs a mesh with vertex colours"
            )
        col = np.asarray(mesh.vertex_colors)
        fi, b = hits.face[m], hits.bary[m]
        w = np.stack([1 - b[:, 0] - b[:, 1], b[:, 0], b[:, 1]], axis=1)
        img[m] = np.einsum("nk,nkc->nc", w, col[f[fi]])
    return img


def render_textured(
    tm: TexturedMesh, camera: Camera, T_wc: np.ndarray, background: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Render a textured mesh: the image ``(H, W, C)`` float32 in [0, 1] and the mask of pixels
    that see the mesh ``(H, W)``."""
    hits = raycast_view(make_scene(tm.vertices, tm.faces), camera, T_wc)
    H, W = hits.face.shape
    C = tm.atlas.shape[2]
    img = np.full((H, W, C), background, dtype=np.float32)
    m = hits.mask
    img[m] = tm.sample(hits.face[m], hits.bary[m])
    return img, m


def render_points(
    points: np.ndarray,
    camera: Camera,
    T_wc: np.ndarray,
    colors: np.ndarray | None = None,
    radius: int = 1,
    background: float = 0.0,
) -> np.ndarray:
    """Splat points ``(N, 3)`` as ``(2 radius + 1)``-pixel squares with a z-buffer; ``(H, W, 3)``
    float32. Uncoloured points are shaded by depth (near bright, far dark)."""
    uv, z = project(np.asarray(points, dtype=np.float64), camera, T_wc)
    ok = (z > 1e-6) & np.all(np.isfinite(uv), axis=1)
    uv, z = uv[ok], z[ok]
    if colors is None:
        lo, hi = np.percentile(z, [2, 98]) if len(z) else (0.0, 1.0)
        g = 1.0 - 0.8 * np.clip((z - lo) / max(hi - lo, 1e-9), 0, 1)
        col = np.repeat(g[:, None], 3, axis=1)
    else:
        col = np.asarray(colors, dtype=np.float64)[ok]
        if col.ndim == 1:
            col = np.repeat(col[:, None], 3, axis=1)
    H, W = camera.height, camera.width
    u0 = np.rint(uv[:, 0]).astype(np.int64)
    v0 = np.rint(uv[:, 1]).astype(np.int64)
    zbuf = np.full(H * W, np.inf)
    keys, zs, idx = [], [], []
    for du in range(-radius, radius + 1):
        for dv in range(-radius, radius + 1):
            u, v = u0 + du, v0 + dv
            inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
            keys.append((v * W + u)[inside])
            zs.append(z[inside])
            idx.append(np.nonzero(inside)[0])
    key, zz, ii = np.concatenate(keys), np.concatenate(zs), np.concatenate(idx)
    np.minimum.at(zbuf, key, zz)
    win = zz <= zbuf[key]
    img = np.full((H * W, 3), background, dtype=np.float32)
    img[key[win]] = col[ii[win]]
    return img.reshape(H, W, 3)


def depth_map(
    mesh: o3d.geometry.TriangleMesh | TexturedMesh, camera: Camera, T_wc: np.ndarray
) -> np.ndarray:
    """Z-depth of ``mesh`` seen from ``camera`` at ``T_wc``, ``(H, W)`` metres (inf on a miss)."""
    v, f = _arrays(mesh)
    o, d = camera_rays(camera, T_wc)
    return cast_rays(make_scene(v, f), np.ascontiguousarray(o), d).depth
