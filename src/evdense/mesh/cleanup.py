"""Mesh clean-up: repairs, small components, small holes, Taubin smoothing, decimation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from evdense.log import get_logger

log = get_logger("mesh.cleanup")


@dataclass
class CleanupConfig:
    """Settings of the mesh clean-up that follows either mesher."""

    min_component_fraction: float = 0.02
    """Connected components with fewer faces than this fraction of the largest one are removed."""
    max_hole_edges: int = 40
    """Holes whose boundary has at most this many edges are closed (a fan around their centroid)."""
    smooth_iterations: int = 5
    """Taubin smoothing iterations (lambda 0.5, mu -0.53: smooths without shrinking); 0 for none."""
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


def close_small_holes(mesh: o3d.geometry.TriangleMesh, max_edges: int) -> o3d.geometry.TriangleMesh:
    """Close holes bounded by at most ``max_edges`` edges with a fan around the loop's centroid,
    oriented like the surrounding faces."""
    if max_edges < 3 or len(mesh.triangles) == 0:
        return mesh
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.triangles)
    new_v, new_f = [], []
    nv = len(v)
    for loop in boundary_loops(f):
        if len(loop) > max_edges:
            continue
        if len(loop) == 3:
            new_f.append(loop[::-1][None])
            continue
        c = nv + len(new_v)
        new_v.append(v[loop].mean(0))
        a, b = loop, np.roll(loop, -1)
        new_f.append(np.stack([b, a, np.full(len(loop), c)], axis=1))
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


def clean_mesh(
    mesh: o3d.geometry.TriangleMesh, config: CleanupConfig | None = None
) -> o3d.geometry.TriangleMesh:
    """Repair, drop small components, close small holes, smooth and decimate (see
    :class:`CleanupConfig`); returns a new mesh with vertex normals."""
    config = config or CleanupConfig()
    mesh = o3d.geometry.TriangleMesh(mesh)
    repair(mesh)
    remove_small_components(mesh, config.min_component_fraction)
    mesh = close_small_holes(mesh, config.max_hole_edges)
    repair(mesh)
    if config.smooth_iterations > 0 and len(mesh.triangles):
        colors = np.asarray(mesh.vertex_colors).copy() if mesh.has_vertex_colors() else None
        mesh = mesh.filter_smooth_taubin(number_of_iterations=config.smooth_iterations)
        if colors is not None:
            mesh.vertex_colors = o3d.utility.Vector3dVector(colors)
    if 0 < config.target_faces < len(mesh.triangles):
        n0 = len(mesh.triangles)
        mesh = mesh.simplify_quadric_decimation(config.target_faces)
        log.info("decimated %d -> %d faces", n0, len(mesh.triangles))
        repair(mesh)
    mesh.compute_vertex_normals()
    return mesh
