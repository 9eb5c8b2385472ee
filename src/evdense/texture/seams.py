"""Step 4: seam levelling, an additive colour correction per (vertex, chart) by sparse least squares."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import factorized

from evdense.log import get_logger
from evdense.mesh.geometry import (
    face_normals,
    project,
    sample_bilinear,
)
from evdense.mesh.views import Views
from evdense.texture.model import TextureConfig

log = get_logger("texture")


# Over 80 lines on purpose: one sparse least-squares system (unknowns, seam constraints,
# regulariser, solve, per-corner corrections), built in order over arrays every step shares.
def level_seams(
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
