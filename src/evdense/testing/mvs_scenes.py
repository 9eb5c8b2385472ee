"""Exact synthetic stereo inputs for tests and benchmarks: textured planes and a textured box,
rendered by ray casting (no rendering library needed for planes; open3d for meshes)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from evdense.mvs.patchmatch import StereoView
from evdense.poses import invert_pose, look_at


def noise_texture(size: int = 512, blur: float = 1.2, seed: int = 0) -> np.ndarray:
    """A ``(size, size)`` float texture in [0, 1]: blurred white noise plus a coarser layer."""
    rng = np.random.default_rng(seed)
    fine = gaussian_filter(rng.random((size, size)), blur, mode="wrap")
    coarse = gaussian_filter(rng.random((size, size)), 6 * blur, mode="wrap")
    t = (fine - fine.mean()) / (fine.std() + 1e-12) + 0.7 * (coarse - coarse.mean()) / (
        coarse.std() + 1e-12
    )
    t = (t - t.min()) / (t.max() - t.min() + 1e-12)
    return t.astype(np.float32)


def sample_texture(tex: np.ndarray, u: np.ndarray, v: np.ndarray, texel: float) -> np.ndarray:
    """Bilinear, wrapped lookup of ``tex`` at surface coordinates ``(u, v)`` (metres; ``texel``
    metres per texel)."""
    return map_coordinates(tex, [v / texel, u / texel], order=1, mode="grid-wrap").astype(
        np.float32
    )


@dataclass(frozen=True)
class Plane:
    """An infinite textured plane: a point on it, its unit normal (world frame), texel size (m)."""

    point: np.ndarray
    normal: np.ndarray
    texel: float = 0.01

    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        n = np.asarray(self.normal, np.float64) / np.linalg.norm(self.normal)
        a = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
        e1 = np.cross(n, a)
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(n, e1)


def render_plane(
    plane: Plane,
    K: np.ndarray,
    T_wc: np.ndarray,
    width: int,
    height: int,
    tex: np.ndarray,
    supersample: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Render a plane seen by a pinhole camera (pose camera-to-world ``T_wc``).

    Returns the grey image ``(H, W)`` float32 in [0, 1] (the mean of ``supersample`` x
    ``supersample`` rays per pixel, so that textures do not alias; 0 where the plane is not hit)
    and the exact z-depth at the pixel centres ``(H, W)`` (0 where not hit).
    """
    s = max(1, int(supersample))
    sub = (np.arange(s) + 0.5) / s - 0.5
    u, v = np.meshgrid(
        (np.arange(width)[:, None] + sub[None]).ravel(),
        (np.arange(height)[:, None] + sub[None]).ravel(),
    )
    R, C = T_wc[:3, :3], T_wc[:3, 3]
    n = np.asarray(plane.normal, np.float64) / np.linalg.norm(plane.normal)
    e1, e2 = plane.basis()

    def cast(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rays_w = (np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T) @ R.T
        den = rays_w @ n
        t = ((np.asarray(plane.point) - C) @ n) / np.where(np.abs(den) > 1e-12, den, np.nan)
        hit = np.isfinite(t) & (t > 0)
        t = np.where(hit, t, 0.0)
        return t, hit, C + rays_w * t[..., None] - np.asarray(plane.point)

    _, hit_s, rel = cast(u.astype(np.float64), v.astype(np.float64))
    val = np.where(hit_s, sample_texture(tex, rel @ e1, rel @ e2, plane.texel), 0.0)
    img = val.reshape(height, s, width, s).mean(axis=(1, 3)).astype(np.float32)
    uc, vc = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    depth, hit, _ = cast(uc, vc)
    return np.where(hit, img, 0.0).astype(np.float32), np.where(hit, depth, 0.0).astype(np.float32)


def view_from_pose(image: np.ndarray, K: np.ndarray, T_wc: np.ndarray) -> StereoView:
    """A :class:`StereoView` from an image, intrinsics and a camera-to-world pose."""
    T_cw = invert_pose(np.asarray(T_wc, np.float64))
    return StereoView(
        image=np.asarray(image, np.float32),
        K=np.asarray(K, np.float64),
        R=T_cw[:3, :3],
        t=T_cw[:3, 3],
    )


def plane_scene(
    plane: Plane,
    centers: list[np.ndarray],
    target: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    seed: int = 0,
) -> tuple[list[StereoView], list[np.ndarray], list[np.ndarray]]:
    """Views of ``plane`` from cameras at ``centers`` looking at ``target`` (y-down image, world z
    up); returns the views, the exact depth maps and the camera-to-world poses."""
    tex = noise_texture(seed=seed)
    views, depths, poses = [], [], []
    for c in centers:
        T = look_at(np.asarray(c, np.float64), np.asarray(target, np.float64), up=(0.0, -1.0, 0.0))
        img, depth = render_plane(plane, K, T, width, height, tex)
        views.append(view_from_pose(img, K, T))
        depths.append(depth)
        poses.append(T)
    return views, depths, poses
