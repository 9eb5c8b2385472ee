"""Step 3: charts of faces with one view, packed into one atlas."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components


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


def rasterise(
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


def layout(
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
