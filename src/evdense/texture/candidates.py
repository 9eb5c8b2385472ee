"""Step 1: which views may texture each face, and how well (projected area)."""

from __future__ import annotations

import numpy as np

from evdense.mesh.geometry import (
    face_normals,
    in_image,
    make_scene,
    project,
    raycast_view,
)
from evdense.mesh.views import Views
from evdense.texture.model import TextureConfig


# --- 1. candidates ----------------------------------------------------------------------------
def view_candidates(
    vertices: np.ndarray, faces: np.ndarray, views: Views, config: TextureConfig | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which views may texture which faces: arrays ``face, view, quality`` (quality = projected
    area in square pixels), one entry per usable (face, view) pair."""
    config = config or TextureConfig()
    scene = make_scene(vertices, faces)
    normals, _ = face_normals(vertices, faces)
    tri = vertices[faces]
    cent = tri.mean(axis=1)
    shrunk = cent[:, None] + 0.8 * (tri - cent[:, None])
    samples = np.concatenate([cent[:, None], shrunk], axis=1).reshape(-1, 3)
    out_f, out_v, out_q = [], [], []
    for i in range(len(views)):
        cam, T = views.cameras[i], views.poses[i]
        to_cam = T[:3, 3] - cent
        cosang = np.einsum("ij,ij->i", normals, to_cam) / np.maximum(
            np.linalg.norm(to_cam, axis=1), 1e-12
        )
        ok = cosang >= config.min_facing_cos
        uv, z = project(tri.reshape(-1, 3), cam, T)
        ok &= np.all((in_image(uv, cam, config.border) & (z > 0)).reshape(-1, 3), axis=1)
        if not ok.any():
            continue
        depth = raycast_view(scene, cam, T).depth
        idx = np.nonzero(ok)[0]
        s = samples.reshape(-1, 4, 3)[idx].reshape(-1, 3)
        suv, sz = project(s, cam, T)
        ui = np.clip(np.rint(suv[:, 0]), 0, cam.width - 1).astype(np.int64)
        vi = np.clip(np.rint(suv[:, 1]), 0, cam.height - 1).astype(np.int64)
        vis = sz <= depth[vi, ui] * (1 + config.depth_tolerance)
        idx = idx[np.all(vis.reshape(-1, 4), axis=1)]
        p = uv.reshape(-1, 3, 2)[idx]
        area = 0.5 * np.abs(
            (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
            - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])
        )
        out_f.append(idx)
        out_v.append(np.full(len(idx), i))
        out_q.append(area)
    if not out_f:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(out_f), np.concatenate(out_v), np.concatenate(out_q)
