"""Exact synthetic inputs for tests and benchmarks of the mesh stages: simple meshes, cameras
around them, procedural colours and the images they make (no simulator needed)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import open3d as o3d

from evdense.camera import Camera
from evdense.mesh.geometry import camera_rays, face_normals, make_scene, raycast_view
from evdense.mesh.views import Views
from evdense.poses import look_at

ColourFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""Colour of surface points: ``(points (N, 3), normals (N, 3)) -> (N, C)`` in [0, 1]."""


def box_mesh(
    size: float = 1.0, n: int = 4, center=(0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """A cube of side ``size`` centred at ``center``, each side an ``n x n`` grid of quads split in
    two triangles; outward oriented. Returns ``vertices (V, 3)`` and ``faces (F, 3)`` (vertices on
    edges are shared)."""
    s = np.linspace(-0.5, 0.5, n + 1) * size
    verts, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            a, b = [k for k in range(3) if k != axis]
            gu, gv = np.meshgrid(s, s, indexing="ij")
            p = np.zeros((n + 1, n + 1, 3))
            p[..., axis] = sign * 0.5 * size
            p[..., a], p[..., b] = gu, gv
            base = sum(len(x) for x in verts)
            verts.append(p.reshape(-1, 3))
            i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
            v00 = base + i * (n + 1) + j
            v10, v01, v11 = v00 + (n + 1), v00 + 1, v00 + n + 2
            f = np.concatenate(
                [
                    np.stack([v00, v10, v11], -1).reshape(-1, 3),
                    np.stack([v00, v11, v01], -1).reshape(-1, 3),
                ]
            )
            faces.append(f)
    v = np.concatenate(verts)
    f = np.concatenate(faces)
    # Orient outwards (the box is convex and centred at the origin here).
    fn, _ = face_normals(v, f)
    inward = np.einsum("ij,ij->i", fn, v[f].mean(axis=1)) < 0
    f[inward] = f[inward][:, [0, 2, 1]]
    v = v + np.asarray(center, dtype=np.float64)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32))
    )
    mesh.remove_duplicated_vertices()
    return np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64)


def grid_plane(size: float = 2.0, n: int = 20, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A square ``size`` wide in the plane ``z``, an ``n x n`` grid of quads (normals +z)."""
    s = np.linspace(-0.5, 0.5, n + 1) * size
    gx, gy = np.meshgrid(s, s, indexing="ij")
    v = np.stack([gx, gy, np.full_like(gx, z)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = i * (n + 1) + j
    v10, v01, v11 = v00 + (n + 1), v00 + 1, v00 + n + 2
    f = np.concatenate(
        [np.stack([v00, v10, v11], -1).reshape(-1, 3), np.stack([v00, v11, v01], -1).reshape(-1, 3)]
    )
    return v, f.astype(np.int64)


def sphere_mesh(radius: float = 1.0, resolution: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere (open3d) of ``radius`` metres."""
    m = o3d.geometry.TriangleMesh.create_sphere(radius, resolution)
    return np.asarray(m.vertices).copy(), np.asarray(m.triangles).astype(np.int64)


def orbit_poses(
    n: int, radius: float, target=(0.0, 0.0, 0.0), elevation_deg: float = 25.0, phase: float = 0.0
) -> np.ndarray:
    """``n`` camera-to-world poses on a circle of ``radius`` metres at ``elevation_deg`` above the
    target's horizontal plane, all looking at ``target``; ``(n, 4, 4)``."""
    target = np.asarray(target, dtype=np.float64)
    el = np.deg2rad(elevation_deg)
    poses = []
    for k in range(n):
        th = phase + 2 * np.pi * k / n
        eye = target + radius * np.array(
            [np.cos(th) * np.cos(el), np.sin(th) * np.cos(el), np.sin(el)]
        )
        poses.append(look_at(eye, target))
    return np.stack(poses)


def smooth_colour(
    points: np.ndarray, normals: np.ndarray | None = None, freq: float = 6.0
) -> np.ndarray:
    """A smooth procedural RGB texture of world position (sums of sines), ``(N, 3)`` in [0.1, 0.9]."""
    A = np.array([[1.0, 0.3, -0.5], [-0.4, 1.0, 0.6], [0.5, -0.7, 1.0]])
    ph = np.array([0.3, 1.7, 2.9])
    x = points @ A.T * freq
    return 0.5 + 0.2 * np.sin(x + ph) + 0.2 * np.sin(1.9 * x[:, [1, 2, 0]] + ph[::-1])


def render_colour(
    vertices: np.ndarray,
    faces: np.ndarray,
    camera: Camera,
    T_wc: np.ndarray,
    colour: ColourFn,
    background: float = 0.0,
    supersample: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Image ``(H, W, C)`` of a mesh whose surface colour is ``colour(points, normals)``, and the
    depth ``(H, W)`` (z, inf on a miss). ``supersample`` > 1 averages ``s x s`` rays per pixel."""
    scene = make_scene(vertices, faces)
    fn, _ = face_normals(vertices, faces)
    cam = camera.scaled(supersample) if supersample > 1 else camera
    hits = raycast_view(scene, cam, T_wc)
    m = hits.mask
    _, d = camera_rays(cam, T_wc)
    pts = T_wc[:3, 3] + d[m] * hits.depth[m][:, None]
    col = colour(pts, fn[hits.face[m]])
    img = np.full((*hits.face.shape, col.shape[1]), background, dtype=np.float64)
    img[m] = col
    depth = hits.depth
    if supersample > 1:
        s = supersample
        H, W = camera.height, camera.width
        img = img[: H * s, : W * s].reshape(H, s, W, s, -1).mean(axis=(1, 3))
        depth = raycast_view(scene, camera, T_wc).depth
    return img.astype(np.float32), depth


def make_views(
    vertices: np.ndarray,
    faces: np.ndarray,
    camera: Camera,
    poses: np.ndarray,
    colour: ColourFn,
    supersample: int = 2,
) -> Views:
    """In-memory :class:`Views` of the mesh rendered from each pose with ``colour``."""
    images = [
        render_colour(vertices, faces, camera, T, colour, supersample=supersample)[0] for T in poses
    ]
    return Views(
        cameras=[camera] * len(poses),
        poses=np.asarray(poses),
        names=[f"{i:06d}.png" for i in range(len(poses))],
        images=images,
    )


def sample_cloud(
    vertices: np.ndarray,
    faces: np.ndarray,
    num_points: int,
    noise: float = 0.0,
    outliers: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """A cloud sampled uniformly on the mesh: points ``(N, 3)`` with Gaussian noise of std ``noise``
    metres along the normal, plus ``outliers`` (fraction of N) uniform in the bounding box grown by
    25%; and unit normals ``(N, 3)`` (random for outliers)."""
    rng = np.random.default_rng(seed)
    fn, area = face_normals(vertices, faces)
    tri = rng.choice(len(faces), size=num_points, p=area / area.sum())
    r1, r2 = rng.random(num_points), rng.random(num_points)
    s = np.sqrt(r1)
    w = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    pts = np.einsum("nk,nkc->nc", w, vertices[faces[tri]])
    nrm = fn[tri]
    pts = pts + nrm * rng.normal(scale=noise, size=(num_points, 1)) if noise > 0 else pts
    k = int(round(outliers * num_points))
    if k:
        lo, hi = vertices.min(0), vertices.max(0)
        pad = 0.25 * (hi - lo)
        op = rng.uniform(lo - pad, hi + pad, size=(k, 3))
        on = rng.normal(size=(k, 3))
        on /= np.linalg.norm(on, axis=1, keepdims=True)
        pts = np.concatenate([pts, op])
        nrm = np.concatenate([nrm, on])
    return pts, nrm
