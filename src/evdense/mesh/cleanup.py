"""Mesh clean-up: repairs, small components, small holes, Taubin smoothing, decimation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from evdense.log import get_logger
from evdense.mesh.geometry import edges_of

log = get_logger("mesh.cleanup")


@dataclass
class CleanupConfig:
    """Settings of the mesh clean-up that follows either mesher."""

    min_component_fraction: float = 0.02
    """Connected components with fewer faces than this fraction of the largest one are removed."""
    max_hole_edges: int = 40
    """Holes whose boundary has at most this many edges, and whose perimeter is at most this many
    median edge lengths, are closed (a fan around their centroid)."""
    max_hole_nonplanarity: float = 0.2
    """A hole of more than three edges is closed only when its boundary is nearly planar: the RMS
    distance of the loop to its best-fit plane at most this fraction of the loop's RMS radius. Larger
    or twisted openings are where the surface really ends (a gap between objects, an unseen side),
    and a fan across them would be surface that is not there."""
    smooth_iterations: int = 0
    """Taubin smoothing iterations (lambda 0.5, mu -0.53: smooths without shrinking); 0 for none,
    the default: on the default scene's real clouds every iteration lowered the mesh's F-score
    (precision rises, recall falls more); on a synthetic cloud with 8.7 mm of Gaussian noise 5
    iterations raised it (docs/benchmarks.md)."""
    smooth_boundary: str = "free"
    """What Taubin smoothing does with vertices on open borders: ``free`` treats them as any other
    vertex (the border creeps inwards a little), ``curve`` smooths them along the border only,
    ``pinned`` holds them in place (and keeps the spikes noise left there). Free scored best on the
    synthetic check, pinned on the default scene (``benchmarks/bench_cleanup.py``)."""
    target_faces: int = 500_000
    """Quadric decimation down to this many faces when the mesh has more; 0 keeps every face."""


def repair(mesh: o3d.geometry.TriangleMesh) -> o3d.geometry.TriangleMesh:
    """Remove duplicated and unreferenced vertices, duplicated and degenerate faces, and faces on
    non-manifold edges (in place; returns the mesh)."""
    mesh.remove_duplicated_vertices()
    mesh.remove_duplicated_triangles()
    mesh.remove_degenerate_triangles()
    mesh.remove_non_manifold_edges()
    mesh.remove_unreferenced_vertices()
    return mesh


def remove_small_components(
    mesh: o3d.geometry.TriangleMesh, min_fraction: float
) -> o3d.geometry.TriangleMesh:
    """Drop connected components with fewer than ``min_fraction`` times the faces of the largest."""
    if len(mesh.triangles) == 0 or min_fraction <= 0:
        return mesh
    labels, counts, _ = mesh.cluster_connected_triangles()
    labels, counts = np.asarray(labels), np.asarray(counts)
    small = counts < min_fraction * counts.max()
    if small.any():
        mesh.remove_triangles_by_mask(small[labels])
        mesh.remove_unreferenced_vertices()
        log.info(
            "removed %d small components (%d faces)", int(small.sum()), int(counts[small].sum())
        )
    return mesh


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed loops of boundary half-edges ``a -> b`` (as vertex sequences), following the faces'
    orientation; loops through a vertex with several boundary edges leaving it are skipped."""
    he = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    n = int(faces.max()) + 1
    key = he[:, 0] * n + he[:, 1]
    rev = he[:, 1] * n + he[:, 0]
    bnd = he[~np.isin(key, rev)]
    if len(bnd) == 0:
        return []
    starts, counts = np.unique(bnd[:, 0], return_counts=True)
    ambiguous = set(starts[counts > 1].tolist())
    nxt = {int(a): int(b) for a, b in bnd if int(a) not in ambiguous}
    loops, seen = [], set()
    for a0 in list(nxt):
        if a0 in seen:
            continue
        loop, a, ok = [a0], nxt[a0], True
        seen.add(a0)
        while a != a0:
            if a not in nxt or a in seen:
                ok = False
                break
            seen.add(a)
            loop.append(a)
            a = nxt[a]
        if ok:
            loops.append(np.array(loop))
    return loops


def loop_nonplanarity(points: np.ndarray) -> float:
    """RMS distance of a closed loop's points to their best-fit plane over their RMS distance to
    the centroid (0 for a planar loop; about 0.35 for a loop bent like a saddle or a box corner)."""
    d = points - points.mean(0)
    radius = float(np.sqrt((d**2).sum(1).mean()))
    if radius == 0:
        return 0.0
    off_plane = float(np.linalg.svd(d, compute_uv=False)[-1]) / np.sqrt(len(points))
    return off_plane / radius


def close_small_holes(
    mesh: o3d.geometry.TriangleMesh, max_edges: int, max_nonplanarity: float = 0.2
) -> o3d.geometry.TriangleMesh:
    """Close holes with a fan around the loop's centroid, oriented like the surrounding faces.

    A hole is closed when its boundary has at most ``max_edges`` edges, its perimeter is at most
    ``max_edges`` median edge lengths of the mesh, and (beyond a triangle) its boundary is nearly
    planar (:func:`loop_nonplanarity` at most ``max_nonplanarity``). Counting edges alone also
    closes long loops of coarse edges and openings that bend around a corner, inventing surface.
    """
    if max_edges < 3 or len(mesh.triangles) == 0:
        return mesh
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.triangles)
    e = edges_of(f)
    median_edge = float(np.median(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)))
    new_v, new_f = [], []
    nv = len(v)
    skipped = 0
    for loop in boundary_loops(f):
        if len(loop) > max_edges:
            continue
        a, b = loop, np.roll(loop, -1)
        perimeter = float(np.linalg.norm(v[a] - v[b], axis=1).sum())
        if perimeter > max_edges * median_edge or (
            len(loop) > 3 and loop_nonplanarity(v[loop]) > max_nonplanarity
        ):
            skipped += 1
            continue
        if len(loop) == 3:
            new_f.append(loop[::-1][None])
            continue
        c = nv + len(new_v)
        new_v.append(v[loop].mean(0))
        new_f.append(np.stack([b, a, np.full(len(loop), c)], axis=1))
    if skipped:
        log.info("left %d holes open (too long a perimeter or not planar)", skipped)
    if not new_f:
        return mesh
    faces = np.concatenate([f, *new_f])
    verts = np.concatenate([v, np.array(new_v).reshape(-1, 3)])
    out = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(faces.astype(np.int32))
    )
    if mesh.has_vertex_colors() and len(new_v):
        col = np.asarray(mesh.vertex_colors)
        extra = np.full((len(new_v), 3), col.mean(0) if len(col) else 0.5)
        out.vertex_colors = o3d.utility.Vector3dVector(np.concatenate([col, extra]))
    log.info("closed %d small holes", len(new_f))
    return out


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Edges used by a single face ``(E, 2)`` (smaller index first): the open borders."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq[counts == 1]


def boundary_vertices(faces: np.ndarray) -> np.ndarray:
    """Indices of the vertices on an open boundary (on an edge used by a single face)."""
    return np.unique(boundary_edges(faces))


BOUNDARY_MODES = ("free", "curve", "pinned")


def smooth_taubin(
    vertices: np.ndarray,
    faces: np.ndarray,
    iterations: int,
    lam: float = 0.5,
    mu: float = -0.53,
    boundary: str = "free",
) -> np.ndarray:
    """Taubin smoothing with the uniform Laplacian: per iteration a step ``lam`` towards the mean of
    the neighbours and a step ``mu`` back. Returns new vertex positions.

    ``boundary`` says what vertices on open borders do. ``free`` (the default, the classic
    behaviour): like any other vertex; their neighbours all lie on one side, so the border is
    pulled inwards a little every iteration and the surface shrinks. ``pinned``: they stay put,
    which keeps the border but also every spike and flap that noise left on it. ``curve``: they are
    smoothed along the border only (neighbours: the two border vertices either side), which removes
    spikes without the inward pull, but rounds the border's corners.
    """
    from scipy.sparse import coo_matrix

    if boundary not in BOUNDARY_MODES:
        raise ValueError(f"boundary must be one of {BOUNDARY_MODES}, not {boundary!r}")
    n = len(vertices)
    x = np.asarray(vertices, dtype=np.float64).copy()
    if iterations <= 0 or len(faces) == 0:
        return x
    e = edges_of(faces)
    i = np.concatenate([e[:, 0], e[:, 1]])  # (i, j): j is a neighbour of i
    j = np.concatenate([e[:, 1], e[:, 0]])
    on_border = np.zeros(n, bool)
    if boundary != "free":
        be = boundary_edges(faces)
        on_border[be.ravel()] = True
    if boundary == "curve":  # border vertices average their border neighbours only
        inner = ~on_border[i]
        i = np.concatenate([i[inner], be[:, 0], be[:, 1]])
        j = np.concatenate([j[inner], be[:, 1], be[:, 0]])
    deg = np.bincount(i, minlength=n).astype(np.float64)
    mean_of_neighbours = coo_matrix((1.0 / deg[i], (i, j)), shape=(n, n)).tocsr()
    movable = deg > 0
    if boundary == "pinned":
        movable &= ~on_border
    for _ in range(iterations):
        for step in (lam, mu):
            delta = mean_of_neighbours @ x - x
            x[movable] += step * delta[movable]
    return x


def clean_mesh(
    mesh: o3d.geometry.TriangleMesh, config: CleanupConfig | None = None
) -> o3d.geometry.TriangleMesh:
    """Repair, drop small components, close small holes, smooth and decimate (see
    :class:`CleanupConfig`); returns a new mesh with vertex normals."""
    config = config or CleanupConfig()
    mesh = o3d.geometry.TriangleMesh(mesh)
    repair(mesh)
    remove_small_components(mesh, config.min_component_fraction)
    mesh = close_small_holes(mesh, config.max_hole_edges, config.max_hole_nonplanarity)
    repair(mesh)
    if config.smooth_iterations > 0 and len(mesh.triangles):
        smoothed = smooth_taubin(
            np.asarray(mesh.vertices),
            np.asarray(mesh.triangles),
            config.smooth_iterations,
            boundary=config.smooth_boundary,
        )
        mesh.vertices = o3d.utility.Vector3dVector(smoothed)
    if 0 < config.target_faces < len(mesh.triangles):
        n0 = len(mesh.triangles)
        mesh = mesh.simplify_quadric_decimation(config.target_faces)
        log.info("decimated %d -> %d faces", n0, len(mesh.triangles))
        repair(mesh)
    mesh.compute_vertex_normals()
    return mesh
