"""All steps: :func:`texture_mesh_views` turns a mesh and calibrated views into a textured mesh."""

from __future__ import annotations

import time

import numpy as np

from evdense.log import get_logger
from evdense.mesh.geometry import (
    face_adjacency,
    project,
    sample_bilinear,
)
from evdense.mesh.views import Views
from evdense.texture.atlas import face_charts, layout, rasterise
from evdense.texture.candidates import view_candidates
from evdense.texture.model import TextureConfig, TexturedMesh
from evdense.texture.seams import level_seams
from evdense.texture.selection import select_views

log = get_logger("texture")


# Over 80 lines on purpose: the texturing steps in order (view selection, corner coordinates,
# charts and packing, patches, seam levelling, palette), each a few lines of array code over the
# same per-corner arrays; the heavy parts are their own modules (selection, seams, atlas).
def texture_mesh_views(
    vertices: np.ndarray, faces: np.ndarray, views: Views, config: TextureConfig | None = None
) -> TexturedMesh:
    """Texture a mesh (``vertices (V, 3)``, ``faces (F, 3)``) from calibrated ``views``."""
    config = config or TextureConfig()
    t0 = time.monotonic()
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    views = views.at_most(config.max_views)
    F = len(faces)
    adjacency = face_adjacency(faces)
    cand = view_candidates(vertices, faces, views, config)
    labels = select_views(F, cand, adjacency, config.smoothness, config.mrf_cycles)
    t1 = time.monotonic()
    seen = labels >= 0
    log.info(
        "views chosen for %d of %d faces from %d views (%.1f s)",
        int(seen.sum()),
        F,
        len(views),
        t1 - t0,
    )
    chart_of = face_charts(F, adjacency, labels)
    chart_of[~seen] = -1
    images = [views.image(i) for i in range(len(views))]
    C = images[0].shape[2]

    # Per-corner image pixel coordinates in the chosen view.
    corner_px = np.zeros((F, 3, 2))
    for i in np.unique(labels[seen]):
        fi = np.nonzero(labels == i)[0]
        uv, _ = project(vertices[faces[fi]].reshape(-1, 3), views.cameras[i], views.poses[i])
        corner_px[fi] = uv.reshape(-1, 3, 2)

    # Charts, their patch rectangles and the packing.
    ids = np.unique(chart_of[seen])
    order = np.argsort(chart_of[seen], kind="stable")
    seen_faces = np.nonzero(seen)[0][order]
    splits = np.searchsorted(chart_of[seen_faces], ids[1:]) if len(ids) else []
    groups = np.split(seen_faces, splits) if len(ids) else []
    m = config.margin
    lo = np.array([np.floor(corner_px[g].reshape(-1, 2).min(0)) - m for g in groups]).reshape(-1, 2)
    hi = np.array([np.ceil(corner_px[g].reshape(-1, 2).max(0)) + m for g in groups]).reshape(-1, 2)
    extent = hi - lo + 1
    n_unseen = int((~seen).sum())
    scale = 1.0
    for _ in range(20):
        sizes, pos, width, height, H = layout(extent, n_unseen, scale)
        if max(width, H) <= config.max_atlas_size:
            break
        scale *= 0.97 * config.max_atlas_size / max(width, H)
    if scale < 1.0:
        log.warning(
            "atlas limited to %d texels: charts scaled by %.3f", config.max_atlas_size, scale
        )
    pal_cols = max(1, width // 3)
    atlas = np.zeros((H, width, C), dtype=np.float32)
    tex = np.zeros((F, 3, 2))
    # Each chart's patch: texel (a, b) is image pixel lo + (a, b) / scale of the chart's view.
    for k, g in enumerate(groups):
        view = int(labels[g[0]])
        w, h = sizes[k]
        xs = lo[k][0] + np.arange(w) / scale
        ys = lo[k][1] + np.arange(h) / scale
        gx, gy = np.meshgrid(xs, ys)
        patch = sample_bilinear(images[view], gx.ravel(), gy.ravel()).reshape(h, w, C)
        atlas[pos[k][1] : pos[k][1] + h, pos[k][0] : pos[k][0] + w] = patch
        tex[g] = pos[k] + (corner_px[g] - lo[k]) * scale
    t2 = time.monotonic()
    log.info("%d charts packed in a %dx%d atlas (%.1f s)", len(groups), width, H, t2 - t1)

    # Seam levelling: additive correction per (vertex, chart).
    vertex_colors = np.zeros((len(vertices), C))
    vcount = np.zeros(len(vertices))
    if len(groups):
        corr = level_seams(vertices, faces, labels, chart_of, adjacency, images, views, config, C)
        # corner colours (image colour + correction) -> vertex colours
        inst_faces = np.nonzero(seen)[0]
        cols = np.zeros((len(inst_faces), 3, C))
        for i in np.unique(labels[seen]):
            sel = labels[inst_faces] == i
            px = corner_px[inst_faces[sel]].reshape(-1, 2)
            cols[sel] = sample_bilinear(images[i], px[:, 0], px[:, 1]).reshape(-1, 3, C)
        if corr is not None:
            cols += corr[inst_faces]
            grid, _ = rasterise(tex[inst_faces], corr[inst_faces], (H, width), dilate=m + 1.5)
            atlas[:height] += grid[:height].astype(np.float32)
        for k in range(3):
            np.add.at(vertex_colors, faces[inst_faces, k], cols[:, k])
            np.add.at(vcount, faces[inst_faces, k], 1)
    np.clip(atlas, 0, 1, out=atlas)
    mean_col = atlas[:height].reshape(-1, C).mean(0) if height else np.full(C, 0.5)
    known = vcount > 0
    vertex_colors[known] /= vcount[known, None]
    vertex_colors[~known] = mean_col
    vertex_colors = np.clip(vertex_colors, 0, 1)

    # Palette for faces no view saw: a 3x3 block of the mean colour of their vertices.
    if n_unseen:
        uf = np.nonzero(~seen)[0]
        col = vertex_colors[faces[uf]].mean(axis=1)
        k = np.arange(n_unseen)
        bx, by = 3 * (k % pal_cols), height + 3 * (k // pal_cols)
        for dy in range(3):
            for dx in range(3):
                atlas[by + dy, bx + dx] = col
        tex[uf] = np.stack([bx + 1.0, by + 1.0], axis=1)[:, None, :]
    face_uvs = np.stack([(tex[..., 0] + 0.5) / width, 1.0 - (tex[..., 1] + 0.5) / H], axis=-1)
    rgb = vertex_colors if C == 3 else np.repeat(vertex_colors[:, :1], 3, axis=1)
    log.info("textured in %.1f s", time.monotonic() - t0)
    return TexturedMesh(vertices, faces, face_uvs, atlas, labels, rgb)
