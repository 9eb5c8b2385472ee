"""Visibility-based surface reconstruction: Delaunay tetrahedra labelled by an s-t graph cut.

In the line of Labatut et al. (2009) and Jancosek & Pajdla (2011), with the soft visibility
weights of Vu et al. (2012):

1. The cloud (merged on a voxel grid to at most ``max_points``) and the 8 corners of a box
   enclosing it and the cameras are tetrahedralised (``scipy.spatial.Delaunay``).
2. Every line of sight, from a point back to a camera that saw it, is walked exactly through the
   tetrahedra (all rays advanced together, one facet per step, with numpy). Each facet crossed at
   distance ``d`` from the point gets the weight ``1 - exp(-d^2 / (2 sigma^2))`` against "the
   camera side outside and the point side inside" (soft near the point, so noise does not punch
   holes); the cell holding the camera gets "outside" evidence; the cell ``inside_distance``
   behind the point gets "inside" evidence.
3. Each facet also costs ``quality_weight * (1 - min(cos phi_a, cos phi_b))`` to cut, where
   ``phi`` is the angle between the facet and the circumsphere of a cell on each side: facets of
   the true surface (between two large empty spheres) are cheap, facets through the volume dear.
4. Cells that no line of sight crosses (unobserved space) get a weak "inside" prior, so that an
   open surface (a floor) closes into unobserved space rather than growing a hidden second layer.
5. A max-flow / min-cut (PyMaxflow) labels every cell inside (sink) or outside (source); the
   facets between inside and outside cells, oriented outwards, are the mesh. Facets touching the
   helper box corners are dropped (they close the volume far from any data), and so are facets
   whose centroid lies far from every point (large faces bridging unobserved gaps).

Visibility of a point (which cameras saw it) comes from fusion's ``.vis`` file when given;
otherwise :func:`estimate_visibility` keeps, per view, the points in front of the camera, inside
the image, facing it (by their normal) and not behind the cloud's own z-buffer in that view.
Points that no camera saw are left out. Isolated outliers in free space are crossed by many lines
of sight and end up outside; they do not become surface (what remains of them forms small
components that the clean-up removes).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import maxflow
import numpy as np
import open3d as o3d
from scipy.spatial import Delaunay, cKDTree

from evdense.log import get_logger
from evdense.mesh.geometry import in_image, median_spacing, project
from evdense.mesh.views import Views

log = get_logger("mesh.visibility")


@dataclass
class VisibilityConfig:
    """Settings of the visibility (Delaunay + graph-cut) mesher."""

    max_points: int = 200_000
    """Points kept for the tetrahedralisation (merged on a voxel grid beyond this)."""
    max_views_per_point: int = 6
    """Lines of sight kept per point (a seeded random subset of the cameras that saw it)."""
    max_rays: int = 1_500_000
    """Lines of sight walked in all (a seeded random subset beyond this)."""
    sigma: float = 2.0
    """Soft-visibility distance, in median point spacings: facets crossed closer than this to the
    point cost little to cut (noise tolerance)."""
    inside_distance: float = 4.0
    """Distance behind a point, in median point spacings, of the cell that gets "inside" evidence."""
    quality_weight: float = 1.0
    """Weight of the facet-quality (empty-sphere angle) term, relative to one line of sight."""
    max_face_distance: float = 8.0
    """Faces whose centroid is farther than this many median point spacings from every point are
    dropped (large faces spanning unobserved gaps, e.g. between stray points); 0 keeps them."""
    unseen_weight: float = 0.1
    """"Inside" evidence of every cell that no line of sight crosses (unobserved space), relative
    to one line of sight."""
    box_margin: float = 0.2
    """Margin of the helper bounding box, as a fraction of the diagonal of cloud and cameras."""
    max_walk_steps: int = 20_000
    """Facets crossed per line of sight at most (a safety cap; longer walks stop early)."""
    zbuffer_cell: float = 5.0
    """Z-buffer cell size for estimated visibility, in projected median point spacings (>= 1 pixel):
    large enough that a cell always holds a point of the front surface."""
    occlusion_tolerance: float = 1.5
    """A point is visible when its depth is within this many z-buffer cell widths (at its depth)
    of the nearest point in its cell (surfaces tilted up to ~55 degrees pass)."""
    min_facing_cos: float = 0.1
    """Cosine between a point's normal and its direction to the camera needed to count as seen."""
    seed: int = 0
    """Seed of the random subsets."""


def merge_points(
    points: np.ndarray, max_points: int, spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Merge points on a voxel grid until at most ``max_points`` remain.

    Returns merged points ``(M, 3)`` (voxel means) and, per merged point, the index of one original
    point in it ``(M,)`` (to carry attributes such as visibility).
    """
    if len(points) <= max_points:
        return points, np.arange(len(points))
    vs = spacing
    for _ in range(30):
        keys = np.floor(points / vs).astype(np.int64)
        _, first, inv, counts = np.unique(
            keys, axis=0, return_index=True, return_inverse=True, return_counts=True
        )
        if len(first) <= max_points:
            break
        vs *= max(1.05, np.sqrt(len(first) / max_points))
    inv = inv.ravel()
    merged = np.stack([np.bincount(inv, points[:, k]) for k in range(3)], axis=1) / counts[:, None]
    return merged, first


def estimate_visibility(
    points: np.ndarray,
    normals: np.ndarray | None,
    views: Views,
    config: VisibilityConfig | None = None,
    spacing: float | None = None,
) -> list[np.ndarray]:
    """Which views see each point, ``N`` arrays of view indices.

    A view sees a point when the point is in front of it, inside its image, faces it
    (``normal . direction_to_camera >= min_facing_cos``, when normals are given) and is within
    ``occlusion_tolerance`` cell widths of the nearest cloud point in its z-buffer cell.
    """
    config = config or VisibilityConfig()
    spacing = spacing or median_spacing(points)
    n = len(points)
    rows, cols = [], []
    for i in range(len(views)):
        cam, T = views.cameras[i], views.poses[i]
        uv, z = project(points, cam, T)
        ok = (z > 1e-6) & in_image(uv, cam)
        if normals is not None:
            to_cam = T[:3, 3] - points
            cosang = np.einsum("ij,ij->i", normals, to_cam) / np.maximum(
                np.linalg.norm(to_cam, axis=1), 1e-12
            )
            ok &= cosang >= config.min_facing_cos
        idx = np.nonzero(ok)[0]
        if len(idx) == 0:
            continue
        zi = z[idx]
        proj_spacing = np.median(cam.fx * spacing / zi)
        cell = max(1.0, config.zbuffer_cell * proj_spacing)
        gw = int(np.ceil(cam.width / cell)) + 1
        cu = np.floor((uv[idx, 0] + 0.5) / cell).astype(np.int64)
        cv = np.floor((uv[idx, 1] + 0.5) / cell).astype(np.int64)
        key = cv * gw + cu
        zbuf = np.full(key.max() + 1, np.inf)
        np.minimum.at(zbuf, key, zi)
        vis = zi <= zbuf[key] + config.occlusion_tolerance * cell * zi / cam.fx
        rows.append(idx[vis])
        cols.append(np.full(int(vis.sum()), i))
    if not rows:
        return [np.zeros(0, np.int64) for _ in range(n)]
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    order = np.argsort(r, kind="stable")
    r, c = r[order], c[order]
    splits = np.searchsorted(r, np.arange(1, n))
    return np.split(c, splits)


def _circumcentres(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Circumcentres ``(S, 3)`` and radii ``(S,)`` of tetrahedra ``P (S, 4, 3)``."""
    a = P[:, 0]
    b, c, d = P[:, 1] - a, P[:, 2] - a, P[:, 3] - a
    num = (
        np.einsum("ij,ij->i", b, b)[:, None] * np.cross(c, d)
        + np.einsum("ij,ij->i", c, c)[:, None] * np.cross(d, b)
        + np.einsum("ij,ij->i", d, d)[:, None] * np.cross(b, c)
    )
    den = 2.0 * np.einsum("ij,ij->i", b, np.cross(c, d))
    den = np.where(np.abs(den) < 1e-300, 1e-300, den)
    off = num / den[:, None]
    return a + off, np.linalg.norm(off, axis=1)


def _facet_cosines(tri: Delaunay, pts: np.ndarray) -> np.ndarray:
    """``cos phi`` for every (cell, local facet) ``(S, 4)``: the angle between the facet and the
    cell's circumsphere, signed so that 1 means the sphere is tangent to the facet on the cell's side."""
    simp = tri.simplices
    P = pts[simp]
    with np.errstate(over="ignore", invalid="ignore"):
        centre, radius = _circumcentres(P)
    cosines = np.empty((len(simp), 4))
    for f in range(4):
        others = [k for k in range(4) if k != f]
        v0, v1, v2 = P[:, others[0]], P[:, others[1]], P[:, others[2]]
        n = np.cross(v1 - v0, v2 - v0)
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        side = np.sign(np.einsum("ij,ij->i", n, P[:, f] - v0))
        h = side * np.einsum("ij,ij->i", n, centre - v0)
        cosines[:, f] = np.clip(h / np.maximum(radius, 1e-300), -1.0, 1.0)
    return cosines


def _barycentric_transforms(
    pts: np.ndarray, simplices: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per tetrahedron, ``T (S, 3, 3)`` and ``r (S, 3)`` with barycentrics ``b[:3] = T (x - r)``,
    ``b[3] = 1 - sum(b[:3])`` (scipy's convention; its own ``Delaunay.transform`` is far slower)."""
    P = pts[simplices]
    r = P[:, 3]
    a, b, c = P[:, 0] - r, P[:, 1] - r, P[:, 2] - r
    bc, ca, ab = np.cross(b, c), np.cross(c, a), np.cross(a, b)
    det = np.einsum("ij,ij->i", a, bc)
    det = np.where(np.abs(det) < 1e-300, 1e-300, det)
    return np.stack([bc, ca, ab], axis=1) / det[:, None, None], r


def _locate(
    T: np.ndarray,
    r: np.ndarray,
    nbr: np.ndarray,
    simplices: np.ndarray,
    pts: np.ndarray,
    start_cells: np.ndarray,
    targets: np.ndarray,
    max_steps: int,
) -> np.ndarray:
    """The cell holding each target ``(N, 3)``, found by walking from the centroid of a start cell
    (-1 when the target lies outside the triangulation)."""
    origins = pts[simplices[start_cells]].mean(axis=1)
    _, end, _ = _walk_rays(
        T,
        r,
        nbr,
        origins,
        targets - origins,
        start_cells,
        np.zeros(len(targets)),
        np.ones(len(targets)),
        1.0,
        max_steps,
        accumulate=False,
    )
    return end


def _walk_rays(
    T: np.ndarray,
    r: np.ndarray,
    nbr: np.ndarray,
    origins: np.ndarray,
    dirs: np.ndarray,
    start_cells: np.ndarray,
    t0: np.ndarray,
    lengths: np.ndarray,
    sigma: float,
    max_steps: int,
    accumulate: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Walk rays ``origin + t * dir`` (t from ``t0`` to 1) through the tetrahedra, given the
    barycentric transforms ``T, r`` and the neighbour table ``nbr (S, 4)``.

    Returns the accumulated soft weight per (cell, local facet) ``(S * 4,)`` for crossings from the
    cell (origin side) through that facet, the cell holding each ray's end ``(R,)`` (-1 when the
    ray left the triangulation or hit the step cap), and whether each cell was crossed ``(S,)``
    (the first and last empty when not ``accumulate``).
    """
    S = len(nbr)
    weights = np.zeros(S * 4 if accumulate else 0)
    crossed = np.zeros(S if accumulate else 0, dtype=bool)
    end_cell = np.full(len(origins), -1, dtype=np.int64)
    active = np.nonzero(start_cells >= 0)[0]
    cell = start_cells.astype(np.int64).copy()
    t_cur = t0.astype(np.float64).copy()
    two_s2 = 2.0 * sigma * sigma
    for _step in range(max_steps):
        if len(active) == 0:
            break
        k = cell[active]
        Tk = T[k]
        b0 = np.einsum("aij,aj->ai", Tk, origins[active] - r[k])
        db = np.einsum("aij,aj->ai", Tk, dirs[active])
        B0 = np.concatenate([b0, 1.0 - b0.sum(1, keepdims=True)], axis=1)
        DB = np.concatenate([db, -db.sum(1, keepdims=True)], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = np.where(DB < -1e-15, -B0 / DB, np.inf)
        f = np.argmin(tt, axis=1)
        t_exit = np.maximum(tt[np.arange(len(active)), f], t_cur[active])
        done = t_exit >= 1.0
        end_cell[active[done]] = k[done]
        go = ~done
        a_go, k_go, f_go, t_go = active[go], k[go], f[go], t_exit[go]
        if accumulate:
            crossed[k_go] = True
            d = t_go * lengths[a_go]
            np.add.at(weights, k_go * 4 + f_go, 1.0 - np.exp(-(d * d) / two_s2))
        nxt = nbr[k_go, f_go]
        inside = nxt >= 0
        cell[a_go] = nxt
        t_cur[a_go] = t_go
        active = a_go[inside]
    return weights, end_cell, crossed


def visibility_mesh(
    points: np.ndarray,
    visibility: list[np.ndarray],
    centers: np.ndarray,
    config: VisibilityConfig | None = None,
    colors: np.ndarray | None = None,
) -> o3d.geometry.TriangleMesh:
    """Mesh a cloud from its lines of sight (see the module docstring).

    Args:
        points: ``(N, 3)`` metres.
        visibility: per point, the indices into ``centers`` of the cameras that saw it.
        centers: camera centres ``(C, 3)`` metres.
        colors: optional ``(N, 3)`` RGB in [0, 1], carried to the mesh vertices.

    Returns an oriented triangle mesh (normals outwards) whose vertices are input points.
    Raises ``ValueError`` when there is no line of sight or the result is empty.
    """
    config = config or VisibilityConfig()
    t_start = time.monotonic()
    merged, vis, cols, spacing = _seen_points(points, visibility, colors, config.max_points)
    ray_pt, ray_cam = _lines_of_sight(vis, config)

    # Tetrahedralise the points plus a box around points and the cameras that matter.
    used_cams = centers[np.unique(ray_cam)]
    lo = np.minimum(merged.min(0), used_cams.min(0))
    hi = np.maximum(merged.max(0), used_cams.max(0))
    margin = config.box_margin * np.linalg.norm(hi - lo) + 10 * spacing
    lo, hi = lo - margin, hi + margin
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    pts = np.concatenate([merged, corners])
    M = len(merged)
    tri = Delaunay(pts)
    S = len(tri.simplices)
    log.info("Delaunay: %d points, %d tetrahedra (%.1f s)", len(pts), S, time.monotonic() - t_start)

    facet_w, end_cell, behind, crossed = _walk_lines_of_sight(
        tri, pts, merged, centers, ray_pt, ray_cam, spacing, config
    )
    faces = _cut_surface(tri, pts, facet_w, end_cell, behind, crossed, config)
    faces = faces[np.all(faces < M, axis=1)]
    if config.max_face_distance > 0 and len(faces):
        d, _ = cKDTree(merged).query(merged[faces].mean(axis=1), workers=-1)
        far = d > config.max_face_distance * spacing
        if far.any():
            log.info("dropping %d faces far from every point", int(far.sum()))
            faces = faces[~far]
    if len(faces) == 0:
        raise ValueError("visibility mesher: the graph cut found no surface")
    used, inv = np.unique(faces, return_inverse=True)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(merged[used]),
        o3d.utility.Vector3iVector(inv.reshape(-1, 3).astype(np.int32)),
    )
    if cols is not None:
        mesh.vertex_colors = o3d.utility.Vector3dVector(np.clip(cols[used], 0, 1))
    log.info(
        "visibility mesh: %d vertices, %d faces (%.1f s in all)",
        len(used),
        len(faces),
        time.monotonic() - t_start,
    )
    return mesh


def _lines_of_sight(
    vis: list[np.ndarray], config: VisibilityConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Point and camera index of every line of sight, capped per point and in all (seeded)."""
    rng = np.random.default_rng(config.seed)
    ray_pt, ray_cam = [], []
    for i, v in enumerate(vis):
        if len(v) > config.max_views_per_point:
            v = rng.choice(v, config.max_views_per_point, replace=False)
        ray_pt.append(np.full(len(v), i))
        ray_cam.append(np.asarray(v, dtype=np.int64))
    ray_pt = np.concatenate(ray_pt) if ray_pt else np.zeros(0, np.int64)
    ray_cam = np.concatenate(ray_cam) if ray_cam else np.zeros(0, np.int64)
    if len(ray_pt) == 0:
        raise ValueError("visibility mesher: no point is seen by any camera (no line of sight)")
    if len(ray_pt) > config.max_rays:
        keep = np.sort(rng.choice(len(ray_pt), config.max_rays, replace=False))
        ray_pt, ray_cam = ray_pt[keep], ray_cam[keep]
    return ray_pt, ray_cam


def _cut_surface(
    tri: Delaunay,
    pts: np.ndarray,
    facet_w: np.ndarray,
    end_cell: np.ndarray,
    behind: np.ndarray,
    crossed: np.ndarray,
    config: VisibilityConfig,
) -> np.ndarray:
    """Label the tetrahedra inside or outside by a minimum s-t cut over the walked lines of sight
    and return the facets between the two labels, ``(F, 3)`` indices into ``pts``, each oriented
    away from its inside cell."""
    S = len(tri.simplices)
    nbr = tri.neighbors
    # Terminal weights: source = outside, sink = inside.
    src = np.bincount(end_cell[end_cell >= 0], minlength=S).astype(np.float64)
    snk = np.bincount(behind[behind >= 0], minlength=S).astype(np.float64)
    # Space no line of sight went through is unobserved: lean it inside, so that an open surface
    # (a floor, a wall) closes into unobserved space instead of getting a second, hidden layer.
    unseen = ~crossed
    unseen[end_cell[end_cell >= 0]] = False
    snk[unseen] += config.unseen_weight

    # Facets: each interior facet once (cell a < neighbour b), and hull facets.
    cell_idx = np.repeat(np.arange(S), 4)
    loc = np.tile(np.arange(4), S)
    nb = nbr.ravel()
    cosines = _facet_cosines(tri, pts).ravel()
    interior = nb > cell_idx
    a, fa, b = cell_idx[interior], loc[interior], nb[interior]
    fb = np.argmax(nbr[b] == a[:, None], axis=1)
    quality = config.quality_weight * (1.0 - np.minimum(cosines[a * 4 + fa], cosines[b * 4 + fb]))
    # cap(a -> b) is paid when a is outside and b inside: rays crossing from b (point side) to a.
    cap_ab = facet_w[b * 4 + fb] + quality
    cap_ba = facet_w[a * 4 + fa] + quality
    hull = nb < 0
    ha, hf = cell_idx[hull], loc[hull]
    np.add.at(src, ha, facet_w[ha * 4 + hf] + config.quality_weight * (1.0 - cosines[ha * 4 + hf]))

    g = maxflow.Graph[float](S, len(a))
    nodes = g.add_nodes(S)
    g.add_edges(nodes[a], nodes[b], cap_ab, cap_ba)
    g.add_grid_tedges(nodes, src, snk)
    t2 = time.monotonic()
    g.maxflow()
    inside = g.get_grid_segments(nodes)
    log.info(
        "graph cut: %d of %d cells inside (%.1f s)", int(inside.sum()), S, time.monotonic() - t2
    )

    # Facets between inside and outside cells, oriented away from the inside cell.
    cut = inside[a] != inside[b]
    in_cell = np.where(inside[a[cut]], a[cut], b[cut])
    in_loc = np.where(inside[a[cut]], fa[cut], fb[cut])
    hull_cut = inside[ha]
    in_cell = np.concatenate([in_cell, ha[hull_cut]])
    in_loc = np.concatenate([in_loc, hf[hull_cut]])
    simp = tri.simplices[in_cell]
    order = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = np.take_along_axis(simp, order[in_loc], axis=1)
    opp = simp[np.arange(len(simp)), in_loc]
    v0, v1, v2 = pts[faces[:, 0]], pts[faces[:, 1]], pts[faces[:, 2]]
    n = np.cross(v1 - v0, v2 - v0)
    flip = np.einsum("ij,ij->i", n, pts[opp] - v0) > 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def _walk_lines_of_sight(
    tri: Delaunay,
    pts: np.ndarray,
    merged: np.ndarray,
    centers: np.ndarray,
    ray_pt: np.ndarray,
    ray_cam: np.ndarray,
    spacing: float,
    config: VisibilityConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Walk every line of sight from its point back to its camera through the tetrahedra.

    Returns the weight gathered by each cell facet ``(S * 4,)``, and per line (lines of zero
    length left out) the cell where it ends (its camera's, or -1) and the cell just behind its
    point (-1 when not found); last, whether any line crossed each cell.
    """
    p = merged[ray_pt]
    d = centers[ray_cam] - p
    length = np.linalg.norm(d, axis=1)
    ok = length > 1e-9
    p, d, length, ray_pt = p[ok], d[ok], length[ok], ray_pt[ok]
    unit = d / length[:, None]
    eps = 1e-3 * spacing
    T, r = _barycentric_transforms(pts, tri.simplices)
    nbr = tri.neighbors
    incident = tri.vertex_to_simplex[ray_pt]
    steps = config.max_walk_steps
    start = _locate(T, r, nbr, tri.simplices, pts, incident, p + eps * unit, steps)
    behind = _locate(
        T, r, nbr, tri.simplices, pts, incident, p - config.inside_distance * spacing * unit, steps
    )
    t1 = time.monotonic()
    facet_w, end_cell, crossed = _walk_rays(
        T, r, nbr, p, d, start, eps / length, length, config.sigma * spacing, steps
    )
    log.info(
        "walked %d lines of sight (%.1f s; %.1f%% reached their camera)",
        len(p),
        time.monotonic() - t1,
        100.0 * np.mean(end_cell >= 0),
    )
    return facet_w, end_cell, behind, crossed


def _seen_points(
    points: np.ndarray,
    visibility: list[np.ndarray],
    colors: np.ndarray | None,
    max_points: int,
) -> tuple[np.ndarray, list[np.ndarray], np.ndarray | None, float]:
    """The points some camera saw, merged down to ``max_points``: points, their visibility and
    colours, and their median spacing."""
    points = np.asarray(points, dtype=np.float64)
    seen = np.array([len(v) > 0 for v in visibility], dtype=bool)
    if not seen.all():
        # A point no camera saw carries no evidence; in the tetrahedra it would only anchor
        # surfaces in unobserved space.
        log.info("dropping %d points seen by no camera", int((~seen).sum()))
        points = points[seen]
        visibility = [v for v, s in zip(visibility, seen, strict=True) if s]
        colors = colors[seen] if colors is not None else None
    if len(points) < 4:
        raise ValueError(f"visibility mesher: {len(points)} points, need at least 4")
    spacing = median_spacing(points)
    merged, rep = merge_points(points, max_points, spacing)
    if len(merged) < len(points):
        spacing = median_spacing(merged)
        log.info("merged %d points to %d (spacing %.4g m)", len(points), len(merged), spacing)
    vis = [visibility[i] for i in rep]
    cols = colors[rep] if colors is not None else None
    return merged, vis, cols, spacing
