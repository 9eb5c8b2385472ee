"""Small geometry helpers shared by the mesh stages: camera rays, ray casting, projection,
bilinear sampling, face normals and adjacency.

Conventions: poses are camera-to-world ``T_wc`` (x right, y down, z forward); pixel centres are at
integer coordinates; an image ``(H, W, C)`` is indexed ``[v, u]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from evdense.camera import Camera

INVALID = np.uint32(4294967295)  # open3d's RaycastingScene.INVALID_ID


def camera_rays(camera: Camera, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-frame ray origins and directions for every pixel, each ``(H, W, 3)``.

    Directions have unit depth (z = 1 in the camera frame), so a ray parameter is a z-depth in metres.
    """
    d_cam = camera.pixel_rays()
    d = d_cam @ T_wc[:3, :3].T
    o = np.broadcast_to(T_wc[:3, 3], d.shape)
    return o, d


def make_scene(vertices: np.ndarray, faces: np.ndarray) -> o3d.t.geometry.RaycastingScene:
    """An open3d ray-casting scene holding one triangle mesh."""
    scene = o3d.t.geometry.RaycastingScene()
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.int32))
    scene.add_triangles(tm)
    return scene


@dataclass
class Hits:
    """What each pixel's ray hits: depth ``(H, W)`` (z, metres; inf on a miss), face index
    ``(H, W)`` int64 (-1 on a miss), barycentrics ``(H, W, 2)`` ``(b1, b2)`` with the hit point
    ``(1 - b1 - b2) v0 + b1 v1 + b2 v2``, and the geometric face normal ``(H, W, 3)``."""

    depth: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    normal: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        return self.face >= 0


def cast_rays(scene: o3d.t.geometry.RaycastingScene, origins: np.ndarray, dirs: np.ndarray) -> Hits:
    """Cast rays ``(..., 3)`` into ``scene``; the result has the leading shape of ``origins``."""
    shape = origins.shape[:-1]
    rays = np.concatenate([origins.reshape(-1, 3), dirs.reshape(-1, 3)], axis=1).astype(np.float32)
    out = scene.cast_rays(o3d.core.Tensor(rays))
    prim = out["primitive_ids"].numpy()
    face = np.where(prim == INVALID, -1, prim.astype(np.int64))
    return Hits(
        depth=out["t_hit"].numpy().astype(np.float64).reshape(shape),
        face=face.reshape(shape),
        bary=out["primitive_uvs"].numpy().astype(np.float64).reshape(*shape, 2),
        normal=out["primitive_normals"].numpy().astype(np.float64).reshape(*shape, 3),
    )


def raycast_view(scene: o3d.t.geometry.RaycastingScene, camera: Camera, T_wc: np.ndarray) -> Hits:
    """Cast one ray per pixel of ``camera`` at pose ``T_wc``; ``depth`` is the z-depth."""
    o, d = camera_rays(camera, T_wc)
    return cast_rays(scene, np.ascontiguousarray(o), d)


def world_to_camera(points: np.ndarray, T_wc: np.ndarray) -> np.ndarray:
    """World points ``(N, 3)`` to camera-frame points ``(N, 3)``."""
    R, t = T_wc[:3, :3], T_wc[:3, 3]
    return (points - t) @ R


def project(points: np.ndarray, camera: Camera, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points ``(N, 3)``: pixels ``(N, 2)`` and z-depths ``(N,)`` (metres).

    Points at z <= 0 get NaN pixels.
    """
    pc = world_to_camera(points, T_wc)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = camera.project(np.where(z[:, None] > 1e-9, pc, np.nan))
    return uv, z


def in_image(uv: np.ndarray, camera: Camera, margin: float = 0.0) -> np.ndarray:
    """Whether pixels ``(N, 2)`` lie inside the image, ``margin`` pixels from its border."""
    u, v = uv[:, 0], uv[:, 1]
    with np.errstate(invalid="ignore"):
        return (
            (u >= -0.5 + margin)
            & (v >= -0.5 + margin)
            & (u <= camera.width - 0.5 - margin)
            & (v <= camera.height - 0.5 - margin)
        )


def sample_bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img (H, W, C)`` at pixel coordinates ``u, v (N,)``; ``(N, C)``.

    Coordinates are clamped to the image (edge values repeat).
    """
    H, W = img.shape[:2]
    u = np.clip(np.nan_to_num(u), 0, W - 1)
    v = np.clip(np.nan_to_num(v), 0, H - 1)
    u0 = np.minimum(np.floor(u).astype(np.int64), W - 2) if W > 1 else np.zeros(len(u), np.int64)
    v0 = np.minimum(np.floor(v).astype(np.int64), H - 2) if H > 1 else np.zeros(len(v), np.int64)
    u1, v1 = np.minimum(u0 + 1, W - 1), np.minimum(v0 + 1, H - 1)
    a, b = (u - u0)[:, None], (v - v0)[:, None]
    return (
        img[v0, u0] * (1 - a) * (1 - b)
        + img[v0, u1] * a * (1 - b)
        + img[v1, u0] * (1 - a) * b
        + img[v1, u1] * a * b
    )


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit face normals ``(F, 3)`` (right-hand rule) and face areas ``(F,)`` (square metres)."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    n = np.cross(b - a, c - a)
    ln = np.linalg.norm(n, axis=1)
    return n / np.maximum(ln, 1e-30)[:, None], 0.5 * ln


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(V, 3)``."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    n = np.cross(b - a, c - a)
    vn = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vn, faces[:, k], n)
    return vn / np.maximum(np.linalg.norm(vn, axis=1), 1e-30)[:, None]


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """Pairs of faces sharing an edge, ``(E, 2)`` int64 (each pair once; a non-manifold edge links
    consecutive faces around it)."""
    F = len(faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    fid = np.tile(np.arange(F), 3)
    key = e[:, 0].astype(np.int64) * (int(faces.max()) + 1 if F else 1) + e[:, 1]
    order = np.argsort(key, kind="stable")
    key, fid = key[order], fid[order]
    same = key[1:] == key[:-1]
    pairs = np.stack([fid[:-1][same], fid[1:][same]], axis=1)
    return pairs[pairs[:, 0] != pairs[:, 1]]


def edges_of(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges ``(E, 2)`` of a triangle mesh (smaller index first)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def median_spacing(points: np.ndarray, sample: int = 20000, seed: int = 0) -> float:
    """Median distance from a point to its nearest neighbour (metres), on a random sample."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 1.0
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(points), size=min(sample, len(points)), replace=False)
    d, _ = cKDTree(points).query(points[idx], k=2)
    return float(np.median(d[:, 1]))
