"""Texturing a mesh from calibrated views, in the spirit of Waechter et al. (ECCV 2014).

1. Candidates: view ``i`` may texture face ``f`` when the face faces it, its three vertices
   project inside the image (``border`` pixels in) and its centroid and (slightly shrunk) corners
   are not behind the view's depth map (the mesh ray-cast from that view). The quality of a
   candidate is the face's projected area in pixels (resolution, distance and obliquity at once).
2. View selection: a Markov random field over the face adjacency; data cost ``1 - q / q_best``,
   Potts cost ``smoothness`` between neighbouring faces with different views; solved by
   alpha-expansion with graph cuts (PyMaxflow).
3. Charts: connected faces with the same view. Each chart's bounding box in its image (plus a
   margin) is copied into an atlas by shelf packing (scaled down uniformly when the atlas would
   exceed ``max_atlas_size``).
4. Seam levelling: an additive colour correction per (vertex, chart), solved by sparse least
   squares so that colours agree along seam edges (sampled along each edge) and the correction
   varies smoothly inside each chart; it is rasterised into the atlas.
5. Faces no view sees get a flat colour (the mean of their vertices' colours) from a palette.

Export: OBJ + MTL + PNG, and a vertex-coloured PLY.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import maxflow
import numpy as np
import open3d as o3d
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import factorized

from evdense.formats.files import atomic_path
from evdense.log import get_logger
from evdense.mesh.geometry import (
    face_adjacency,
    face_normals,
    in_image,
    make_scene,
    project,
    raycast_view,
    sample_bilinear,
)
from evdense.mesh.views import Views, write_png

log = get_logger("mesh.texture")


@dataclass
class TextureConfig:
    """Settings of view selection, atlas packing and seam levelling."""

    smoothness: float = 1.0
    """Potts weight between neighbouring faces textured from different views (data costs are in [0, 1])."""
    mrf_cycles: int = 2
    """Alpha-expansion sweeps over all views."""
    min_facing_cos: float = 0.1
    """Cosine between a face normal and the direction to the camera needed to use a view."""
    border: float = 2.0
    """Pixels between a face's projection and the image border."""
    depth_tolerance: float = 0.01
    """Relative depth tolerance of the occlusion test against a view's depth map."""
    margin: int = 2
    """Texels of image content kept around each chart (bilinear filtering and mip-mapping at seams)."""
    max_atlas_size: int = 8192
    """Largest atlas side in texels; charts are scaled down uniformly beyond it."""
    level_seams: bool = True
    """Solve the additive seam-levelling correction."""
    seam_smoothness: float = 1.0
    """Weight of the within-chart smoothness of the correction, relative to seam agreement."""
    seam_max_angle: float = 30.0
    """Seams along creases sharper than this (degrees between face normals) are not levelled: the
    two sides are different surfaces, whose colours may differ."""
    seam_max_difference: float = 0.2
    """Seam samples whose colours differ by more than this (in [0, 1] units) are taken for a real
    colour edge (or an occlusion error), not an exposure difference, and not levelled."""
    max_views: int = 200
    """Views used at most (evenly spaced through the list)."""


@dataclass
class TexturedMesh:
    """A mesh with one texture atlas: ``vertices (V, 3)``, ``faces (F, 3)``, per-corner texture
    coordinates ``face_uvs (F, 3, 2)`` (OBJ convention: u right, v up, in [0, 1]) and the atlas
    ``(H, W, C)`` float32 in [0, 1]."""

    vertices: np.ndarray
    faces: np.ndarray
    face_uvs: np.ndarray
    atlas: np.ndarray
    face_view: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """The view that textures each face (-1: none saw it, flat colour)."""
    vertex_colors: np.ndarray | None = None
    """``(V, 3)`` RGB in [0, 1], for the vertex-coloured export."""

    def texel_coords(self) -> np.ndarray:
        """Per-corner atlas pixel coordinates ``(F, 3, 2)`` (x right, y down, texel centres at integers)."""
        H, W = self.atlas.shape[:2]
        x = self.face_uvs[..., 0] * W - 0.5
        y = (1.0 - self.face_uvs[..., 1]) * H - 0.5
        return np.stack([x, y], axis=-1)

    def sample(self, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Atlas colours ``(N, C)`` at points given by face index ``(N,)`` and barycentrics
        ``(N, 2)`` ``(b1, b2)`` (the point ``(1 - b1 - b2) v0 + b1 v1 + b2 v2``)."""
        tc = self.texel_coords()[face]
        w = np.stack([1 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], axis=1)
        xy = np.einsum("nk,nkc->nc", w, tc)
        return sample_bilinear(self.atlas, xy[:, 0], xy[:, 1])


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


# --- 2. view selection ------------------------------------------------------------------------
def _tedges(g, nodes, cost0: np.ndarray, cost1: np.ndarray) -> None:
    """Unary costs of label 0 (source side) and 1 (sink side), made non-negative."""
    d = cost1 - cost0
    g.add_grid_tedges(nodes, np.maximum(d, 0), np.maximum(-d, 0))


def select_views(
    num_faces: int,
    cand: tuple[np.ndarray, np.ndarray, np.ndarray],
    adjacency: np.ndarray,
    smoothness: float,
    cycles: int = 2,
    seed: int = 0,
) -> np.ndarray:
    """One view per face (-1 when none may texture it) minimising data + Potts costs by alpha-expansion.

    Args:
        num_faces: F.
        cand: ``(face, view, quality)`` arrays from :func:`view_candidates`.
        adjacency: ``(E, 2)`` face pairs sharing an edge.
        smoothness: Potts weight.
    """
    f, v, q = cand
    labels = np.full(num_faces, -1, dtype=np.int64)
    if len(f) == 0:
        return labels
    qbest = np.zeros(num_faces)
    np.maximum.at(qbest, f, q)
    cost = 1.0 - q / np.maximum(qbest[f], 1e-12)
    # Initial labels: the best view of each face.
    order = np.lexsort((cost, f))
    first = np.unique(f[order], return_index=True)[1]
    labels[f[order][first]] = v[order][first]
    cur = np.full(num_faces, np.inf)
    cur[f[order][first]] = cost[order][first]
    if smoothness <= 0 or len(adjacency) == 0:
        return labels
    by_view = np.argsort(v, kind="stable")
    bounds = np.searchsorted(v[by_view], np.arange(v.max() + 2))
    ea, eb = adjacency[:, 0], adjacency[:, 1]
    rng = np.random.default_rng(seed)
    view_ids = np.unique(v)

    def energy() -> float:
        seen = labels >= 0
        both = seen[ea] & seen[eb]
        return float(cur[seen].sum() + smoothness * np.sum(labels[ea][both] != labels[eb][both]))

    e0 = energy()
    for _cycle in range(cycles):
        changed = 0
        for alpha in rng.permutation(view_ids):
            sel = by_view[bounds[alpha] : bounds[alpha + 1]]
            fa, ca = f[sel], cost[sel]
            keep = labels[fa] != alpha
            fa, ca = fa[keep], ca[keep]
            if len(fa) == 0:
                continue
            node = np.full(num_faces, -1, dtype=np.int64)
            node[fa] = np.arange(len(fa))
            c0 = cur[fa].copy()
            c1 = ca.copy()
            pa, pb = node[ea], node[eb]
            la, lb = labels[ea], labels[eb]
            # Edges with one variable end: the fixed end adds unary costs.
            for var, fix, lv, lf in ((pa, pb, la, lb), (pb, pa, lb, la)):
                m = (var >= 0) & (fix < 0) & (lf >= 0)
                np.add.at(c0, var[m], smoothness * (lv[m] != lf[m]))
                np.add.at(c1, var[m], smoothness * (lf[m] != alpha))
            # Edges with two variable ends: E00 = w[la != lb], E01 = E10 = w, E11 = 0.
            m = (pa >= 0) & (pb >= 0)
            e00 = smoothness * (la[m] != lb[m])
            # E = E00 + (E10 - E00) x_a + (E11 - E10) x_b + (E01 + E10 - E00 - E11) (1 - x_a) x_b
            np.add.at(c0, pa[m], e00)
            np.add.at(c1, pa[m], smoothness)
            np.add.at(c1, pb[m], -smoothness)
            g = maxflow.Graph[float](len(fa), int(m.sum()))
            nodes = g.add_nodes(len(fa))
            shift = np.minimum(c0, c1)
            _tedges(g, nodes, c0 - shift, c1 - shift)
            g.add_edges(pa[m], pb[m], 2 * smoothness - e00, np.zeros(int(m.sum())))
            g.maxflow()
            switch = g.get_grid_segments(nodes)
            if switch.any():
                labels[fa[switch]] = alpha
                cur[fa[switch]] = ca[switch]
                changed += int(switch.sum())
        if changed == 0:
            break
    log.info("view selection: energy %.1f -> %.1f", e0, energy())
    return labels


# --- 3. charts and atlas ----------------------------------------------------------------------
def face_charts(num_faces: int, adjacency: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Chart index per face: connected components of adjacent faces with the same view."""
    if len(adjacency):
        same = labels[adjacency[:, 0]] == labels[adjacency[:, 1]]
        e = adjacency[same]
    else:
        e = np.zeros((0, 2), np.int64)
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_faces, num_faces))
    return connected_components(A, directed=False)[1]


def shelf_pack(sizes: np.ndarray, width: int) -> tuple[np.ndarray, int]:
    """Place rectangles ``(N, 2)`` (width, height) on shelves of an atlas ``width`` wide.

    Returns the top-left corners ``(N, 2)`` (x, y) and the atlas height.
    """
    order = np.argsort(-sizes[:, 1], kind="stable")
    pos = np.zeros_like(sizes)
    x = y = shelf_h = 0
    for i in order:
        w, h = sizes[i]
        if x + w > width:
            y += shelf_h
            x = shelf_h = 0
        pos[i] = (x, y)
        x += w
        shelf_h = max(shelf_h, h)
    return pos, int(y + shelf_h)


def _rasterise(
    tex: np.ndarray, values: np.ndarray, shape: tuple[int, int], dilate: float
) -> tuple[np.ndarray, np.ndarray]:
    """Interpolate per-corner ``values (F, 3, K)`` over triangles ``tex (F, 3, 2)`` (texel coords)
    onto a grid ``shape``; texels within ``dilate`` texels of a triangle take its clamped value.

    Returns the grid ``(H, W, K)`` and a mask of the texels written.
    """
    H, W = shape
    K = values.shape[2]
    out = np.zeros((H, W, K))
    best = np.full((H, W), np.inf)
    lo = np.floor(tex.min(axis=1) - dilate).astype(np.int64)
    hi = np.ceil(tex.max(axis=1) + dilate).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [W - 1, H - 1])
    nx = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    ny = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    counts = nx * ny
    for chunk in np.array_split(np.arange(len(tex)), max(1, int(counts.sum() // 2_000_000) + 1)):
        cc = counts[chunk]
        if cc.sum() == 0:
            continue
        fi = np.repeat(chunk, cc)
        start = np.repeat(np.cumsum(cc) - cc, cc)
        k = np.arange(len(fi)) - start
        px = lo[fi, 0] + k % nx[fi]
        py = lo[fi, 1] + k // nx[fi]
        a, b, c = tex[fi, 0], tex[fi, 1], tex[fi, 2]
        v0, v1 = b - a, c - a
        den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
        den = np.where(np.abs(den) < 1e-12, 1e-12, den)
        dx, dy = px - a[:, 0], py - a[:, 1]
        b1 = (dx * v1[:, 1] - dy * v1[:, 0]) / den
        b2 = (v0[:, 0] * dy - v0[:, 1] * dx) / den
        bary = np.stack([1 - b1 - b2, b1, b2], axis=1)
        # Distance outside the triangle, in texels (0 inside), from the most negative barycentric.
        edge_len = np.linalg.norm(np.stack([c - b, a - c, b - a], axis=1), axis=2)
        height = 2 * np.abs(den)[:, None] / np.maximum(edge_len, 1e-12)
        dist = np.max(np.maximum(-bary, 0) * height, axis=1)
        ok = dist <= dilate
        px, py, fi, bary, dist = px[ok], py[ok], fi[ok], bary[ok], dist[ok]
        bary = np.maximum(bary, 0)
        bary /= bary.sum(1, keepdims=True)
        # Per texel keep the nearest triangle (inside ones have distance 0).
        order = np.lexsort((dist, py * W + px))
        key = (py * W + px)[order]
        firsts = order[np.r_[True, key[1:] != key[:-1]]]
        px, py, fi, bary, dist = px[firsts], py[firsts], fi[firsts], bary[firsts], dist[firsts]
        better = dist < best[py, px]
        px, py, fi, bary, dist = px[better], py[better], fi[better], bary[better], dist[better]
        best[py, px] = dist
        out[py, px] = np.einsum("nk,nkc->nc", bary, values[fi])
    return out, np.isfinite(best)


def _layout(
    extent: np.ndarray, n_unseen: int, scale: float
) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """Pack chart rectangles ``extent (K, 2)`` (image pixels) at ``scale`` texels per pixel, plus
    a palette of 3x3-texel cells for ``n_unseen`` faces: sizes, positions, width, chart height,
    atlas height."""
    sizes = np.ceil(extent * scale).astype(np.int64) + 1
    total = float(np.sum(sizes[:, 0] * sizes[:, 1])) + 9.0 * n_unseen
    widest = int(sizes[:, 0].max()) if len(sizes) else 3
    width = max(int(np.ceil(np.sqrt(max(total, 1.0) * 1.1))), widest, 3)
    pos, height = shelf_pack(sizes, width) if len(sizes) else (np.zeros((0, 2), np.int64), 0)
    pal_cols = max(1, width // 3)
    pal_rows = int(np.ceil(n_unseen / pal_cols)) if n_unseen else 0
    return sizes, pos, width, height, max(height + 3 * pal_rows, 1)


def texture_mesh_views(
    vertices: np.ndarray, faces: np.ndarray, views: Views, config: TextureConfig | None = None
) -> TexturedMesh:
    """Texture a mesh (``vertices (V, 3)``, ``faces (F, 3)``) from calibrated ``views``."""
    config = config or TextureConfig()
    t0 = time.monotonic()
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(views) > config.max_views:
        keep = np.unique(np.linspace(0, len(views) - 1, config.max_views).round().astype(int))
        views = views.subset(keep)
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
        sizes, pos, width, height, H = _layout(extent, n_unseen, scale)
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
        corr = _level_seams(vertices, faces, labels, chart_of, adjacency, images, views, config, C)
        # corner colours (image colour + correction) -> vertex colours
        inst_faces = np.nonzero(seen)[0]
        cols = np.zeros((len(inst_faces), 3, C))
        for i in np.unique(labels[seen]):
            sel = labels[inst_faces] == i
            px = corner_px[inst_faces[sel]].reshape(-1, 2)
            cols[sel] = sample_bilinear(images[i], px[:, 0], px[:, 1]).reshape(-1, 3, C)
        if corr is not None:
            cols += corr[inst_faces]
            grid, _ = _rasterise(tex[inst_faces], corr[inst_faces], (H, width), dilate=m + 1.5)
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


def _level_seams(
    vertices: np.ndarray,
    faces: np.ndarray,
    labels: np.ndarray,
    chart_of: np.ndarray,
    adjacency: np.ndarray,
    images: list[np.ndarray],
    views: Views,
    config: TextureConfig,
    C: int,
) -> np.ndarray | None:
    """Per-corner additive corrections ``(F, 3, C)`` (zeros for unseen faces), or None when
    levelling is off or there is no seam."""
    if not config.level_seams:
        return None
    seen = labels >= 0
    F = len(faces)
    # Unknowns: one per (vertex, chart).
    fs = np.nonzero(seen)[0]
    inst_key = faces[fs].astype(np.int64) * (chart_of.max() + 1) + chart_of[fs][:, None]
    uniq, inst = np.unique(inst_key.ravel(), return_inverse=True)
    n = len(uniq)
    corner_inst = np.full((F, 3), -1, dtype=np.int64)
    corner_inst[fs] = inst.reshape(-1, 3)
    # Seam edges: adjacent seen faces in different charts, with their shared vertices.
    a, b = adjacency[:, 0], adjacency[:, 1]
    fn, _ = face_normals(vertices, faces)
    smooth = np.einsum("ij,ij->i", fn[a], fn[b]) >= np.cos(np.deg2rad(config.seam_max_angle))
    seam = seen[a] & seen[b] & (chart_of[a] != chart_of[b]) & smooth
    a, b = a[seam], b[seam]
    if len(a) == 0:
        return None
    rows, cols, vals, rhs = [], [], [], []
    r = 0
    ts = np.linspace(0.0, 1.0, 5)
    fa_, fb_ = a, b
    # shared vertices of each face pair, as local corner indices in both faces
    va, vb = faces[fa_], faces[fb_]
    eq = va[:, :, None] == vb[:, None, :]
    la = np.full((len(fa_), 2), -1)
    lb = np.full((len(fa_), 2), -1)
    cnt = np.zeros(len(fa_), dtype=np.int64)
    for i in range(3):
        for j in range(3):
            mm = eq[:, i, j] & (cnt < 2)
            la[mm, cnt[mm]] = i
            lb[mm, cnt[mm]] = j
            cnt[mm] += 1
    ok = cnt == 2
    fa_, fb_, la, lb = fa_[ok], fb_[ok], la[ok], lb[ok]
    E = len(fa_)
    p0 = vertices[faces[fa_, la[:, 0]]]
    p1 = vertices[faces[fa_, la[:, 1]]]
    col_a = np.zeros((len(ts), E, C))
    col_b = np.zeros((len(ts), E, C))
    for ti, t in enumerate(ts):
        pt = (1 - t) * p0 + t * p1
        for fside, out in ((fa_, col_a), (fb_, col_b)):
            for i in np.unique(labels[fside]):
                sel = labels[fside] == i
                uv, _ = project(pt[sel], views.cameras[i], views.poses[i])
                out[ti, sel] = sample_bilinear(images[i], uv[:, 0], uv[:, 1])
    ia0 = corner_inst[fa_, la[:, 0]]
    ia1 = corner_inst[fa_, la[:, 1]]
    ib0 = corner_inst[fb_, lb[:, 0]]
    ib1 = corner_inst[fb_, lb[:, 1]]
    n_rejected = 0
    for ti, t in enumerate(ts):
        # (1-t) g_a0 + t g_a1 - (1-t) g_b0 - t g_b1 = c_b - c_a
        diff = col_b[ti] - col_a[ti]
        keep = np.max(np.abs(diff), axis=1) <= config.seam_max_difference
        n_rejected += int((~keep).sum())
        idx = r + np.arange(int(keep.sum()))
        for inst_, w in ((ia0, 1 - t), (ia1, t), (ib0, -(1 - t)), (ib1, -t)):
            rows.append(idx)
            cols.append(inst_[keep])
            vals.append(np.full(len(idx), w))
        rhs.append(diff[keep])
        r += len(idx)
    if r == 0:
        return None
    # Smoothness inside charts: g_u - g_v = 0 along every edge of every chart.
    e = np.concatenate(
        [corner_inst[fs][:, [0, 1]], corner_inst[fs][:, [1, 2]], corner_inst[fs][:, [2, 0]]]
    )
    e = np.unique(np.sort(e, axis=1), axis=0)
    w = np.sqrt(config.seam_smoothness)
    idx = r + np.arange(len(e))
    rows += [idx, idx]
    cols += [e[:, 0], e[:, 1]]
    vals += [np.full(len(e), w), np.full(len(e), -w)]
    rhs.append(np.zeros((len(e), C)))
    r += len(e)
    A = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r, n)
    )
    B = np.concatenate(rhs)
    N = (A.T @ A + 1e-3 * sp.eye(n)).tocsc()
    solve = factorized(N)
    AtB = A.T @ B
    g = np.stack([solve(AtB[:, k]) for k in range(C)], axis=1)
    corr = np.zeros((F, 3, C))
    corr[fs] = g[corner_inst[fs]]
    res0 = np.sqrt(np.mean(B[: r - len(e)] ** 2))
    res1 = np.sqrt(np.mean((A[: r - len(e)] @ g - B[: r - len(e)]) ** 2))
    log.info(
        "seam levelling: %d unknowns, seam RMS difference %.4f -> %.4f (%d of %d samples taken for colour edges)",
        n,
        res0,
        res1,
        n_rejected,
        n_rejected + r - len(e),
    )
    return corr


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
