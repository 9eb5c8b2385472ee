"""Ray-cast rendering of scenes: linear radiance with mip-mapped (trilinear) texture filtering,
z-depth and triangle ids, with open3d's ``RaycastingScene``.

Texture filtering: a pixel at z-depth ``z`` on a surface tilted by ``theta`` from the ray covers
about ``z / f / |cos(theta)|`` metres of the surface (``f`` focal length, pixels), i.e.
``footprint * texels_per_metre`` texels; the mip level is the log2 of that, so that texture detail
finer than a pixel is averaged (as a real lens and pixel area do) instead of aliasing into
flicker that would fire spurious events when the camera moves.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from evdense.camera import Camera, davis346
from evdense.config import section_from_dict
from evdense.sim.textures import TextureAtlas

if TYPE_CHECKING:
    from evdense.sim.scene import Scene

try:  # numba is optional: without it the numpy path is used (several times slower)
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is installed in the project environment
    HAVE_NUMBA = False

CAMERA_KEYS = ("width", "height", "fx", "fy", "cx", "cy")
DIST_KEYS = ("k1", "k2", "p1", "p2")


@dataclass
class RenderConfig:
    """Settings of the renderer (config section ``simulator.render``)."""

    supersample: int = 1
    """Rays per pixel along each axis; the radiance of the ``s x s`` rays is averaged (1 = one ray)."""
    lod_bias: float = 0.0
    """Added to the mip level (log2 texels per pixel); > 0 blurs textures more, < 0 sharpens them
    (and aliases)."""
    max_anisotropy: float = 8.0
    """Cap on 1/|cos(angle between ray and surface normal)| in the pixel footprint, so grazing
    surfaces are not blurred without bound."""
    radiance_floor: float = 1e-3
    """Smallest radiance a render returns (relative units; ordinary surfaces are about 0.05 to 1),
    so its log is finite."""
    camera: dict = field(default_factory=dict)
    """Intrinsics of the simulated sensor (pixels). Empty = DAVIS346 (346x260, fx = fy = 250). Give
    all of width, height, fx, fy, cx, cy or none of them; k1, k2, p1, p2 (OpenCV radial-tangential
    distortion) may be given alone, on top of the DAVIS346 default."""
    gt_pose_rate_hz: float = 200.0
    """Sampling rate of the ground-truth trajectory file ``gt/trajectory.txt``, Hz."""
    gt_tonemap_percentiles: list[float] = field(default_factory=lambda: [0.1, 99.9])
    """Percentiles of radiance (over all GT frames of a dataset) mapped to 0 and 255 by the log tone
    curve of the GT PNGs."""
    gt_min_frames: int = 60
    """Fewest GT frames (the oracle's images). GT frames are rendered at the conventional camera's
    frame times, or at this many evenly spaced times over the recording when the conventional camera
    takes fewer (fast motion), so that the oracle never has fewer images than the event frames give
    SfM. 0 = always at the conventional camera's times."""

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> RenderConfig:
        """Build from ``simulator.render`` (missing or null keys take defaults); ``ValueError``
        names a bad key."""
        return section_from_dict(cls, d, "simulator.render", drop_none=True)

    def check(self) -> None:
        """Raise ``ValueError`` naming the first key out of range; normalises the percentiles."""
        conf, key = self, "simulator.render"
        if (
            isinstance(conf.supersample, bool)
            or not isinstance(conf.supersample, int)
            or conf.supersample < 1
        ):
            raise ValueError(
                f"{key}.supersample: must be an integer >= 1, got {conf.supersample!r}"
            )
        if not conf.max_anisotropy >= 1:
            raise ValueError(f"{key}.max_anisotropy: must be >= 1, got {conf.max_anisotropy}")
        if not conf.radiance_floor > 0:
            raise ValueError(f"{key}.radiance_floor: must be > 0, got {conf.radiance_floor}")
        if not conf.gt_pose_rate_hz > 0:
            raise ValueError(f"{key}.gt_pose_rate_hz: must be > 0, got {conf.gt_pose_rate_hz}")
        p = conf.gt_tonemap_percentiles
        if not (isinstance(p, list | tuple) and len(p) == 2 and 0 <= p[0] < p[1] <= 100):
            raise ValueError(
                f"{key}.gt_tonemap_percentiles: need [low, high] with 0 <= low < high <= 100, got {p!r}"
            )
        conf.gt_tonemap_percentiles = [float(p[0]), float(p[1])]
        m = conf.gt_min_frames
        if isinstance(m, bool) or not isinstance(m, int) or m < 0:
            raise ValueError(f"{key}.gt_min_frames: must be an integer >= 0, got {m!r}")
        conf.make_camera()  # validates the camera keys

    def make_camera(self) -> Camera:
        """The camera these settings describe."""
        c = dict(self.camera or {})
        key = "simulator.render.camera"
        for k in c:
            if k not in CAMERA_KEYS + DIST_KEYS:
                raise ValueError(
                    f"{key}.{k}: unknown key (known: {', '.join(CAMERA_KEYS + DIST_KEYS)})"
                )
        given = [k for k in CAMERA_KEYS if k in c]
        if given and len(given) != len(CAMERA_KEYS):
            missing = [k for k in CAMERA_KEYS if k not in c]
            raise ValueError(
                f"{key}: give all of {', '.join(CAMERA_KEYS)} or none; missing {', '.join(missing)}"
            )
        base = davis346()
        if given:
            if not (int(c["width"]) > 0 and int(c["height"]) > 0 and c["fx"] > 0 and c["fy"] > 0):
                raise ValueError(f"{key}: width, height, fx, fy must be > 0")
            base = Camera(
                int(c["width"]), int(c["height"]), *(float(c[k]) for k in CAMERA_KEYS[2:])
            )
        dist = tuple(float(c.get(k, 0.0)) for k in DIST_KEYS)
        return Camera(base.width, base.height, base.fx, base.fy, base.cx, base.cy, dist)  # type: ignore[arg-type]


@dataclass
class RenderOutput:
    """One rendered view (all ``(H, W)`` at the camera's resolution)."""

    radiance: np.ndarray
    """float32 linear radiance, >= the radiance floor."""
    depth: np.ndarray
    """float32 z-depth along the optical axis, metres; 0 where a ray hits nothing."""
    triangle_ids: np.ndarray
    """int64 index into ``scene.triangles`` of the surface seen at the pixel centre; -1 for none."""


class Renderer:
    """Renders a :class:`~evdense.sim.scene.Scene` from camera-to-world poses.

    ``supersample``: rays per pixel along each axis (``None``: the scene's ``render.supersample``).
    ``backend``: shading kernel, ``auto`` (numba when installed), ``numba`` or ``numpy`` (same result).
    One renderer reuses its ray buffers: use one per thread.
    """

    def __init__(self, scene: Scene, supersample: int | None = None, backend: str = "auto"):
        import open3d as o3d

        self._o3c = o3d.core
        self.scene = scene
        self.camera = scene.camera
        conf = scene.render
        self.supersample = int(conf.supersample if supersample is None else supersample)
        if self.supersample < 1:
            raise ValueError(f"supersample: must be >= 1, got {supersample}")
        self.radiance_floor = np.float32(conf.radiance_floor)
        if backend == "auto":
            backend = "numba" if HAVE_NUMBA else "numpy"
        if backend not in ("numba", "numpy") or (backend == "numba" and not HAVE_NUMBA):
            raise ValueError(
                f"backend: {backend!r} not available (auto, numba, numpy; numba installed: {HAVE_NUMBA})"
            )
        self.backend = backend
        self._rc = o3d.t.geometry.RaycastingScene()
        self._rc.add_triangles(
            o3d.core.Tensor(scene.vertices.astype(np.float32)),
            o3d.core.Tensor(scene.triangles.astype(np.uint32)),
        )
        # per-triangle shading arrays (float32, contiguous): uv = uv0 + b1 * e1 + b2 * e2
        uv = scene.tri_uv.astype(np.float32)
        self._uv0 = np.ascontiguousarray(uv[:, 0])
        self._e1 = np.ascontiguousarray(uv[:, 1] - uv[:, 0])
        self._e2 = np.ascontiguousarray(uv[:, 2] - uv[:, 0])
        self._tex = scene.tri_texture.astype(np.int64)
        self._gain = scene.tri_gain.astype(np.float32)
        self._atlas = TextureAtlas.build(scene.textures)
        self._max_level = (self._atlas.num_levels - 1).astype(np.float32)[self._tex]
        self._min_cos = np.float32(1.0 / conf.max_anisotropy)
        self._views: dict[int, _View] = {}
        # log2 texels per pixel at depth 1 and cos 1, per triangle (focal length set per view)
        self._level0 = (scene.tri_log2_tpm + np.float32(conf.lod_bias)).astype(np.float32)

    # -- public API ------------------------------------------------------------------------
    def radiance(self, T_wc: np.ndarray) -> np.ndarray:
        """Linear radiance ``(H, W)`` float32 (> 0) seen from camera-to-world pose ``T_wc`` ``(4, 4)``."""
        view = self._view(self.supersample)
        hit = self._cast(view, T_wc)
        rad = self._shade(view, hit)
        s = self.supersample
        if s > 1:  # box filter: strided sums beat reshape().mean() several times over
            acc = rad[0::s, 0::s].copy()
            for i in range(s):
                for j in range(s):
                    if i or j:
                        acc += rad[i::s, j::s]
            acc *= np.float32(1.0 / (s * s))
            rad = acc
        return rad

    def render(self, T_wc: np.ndarray) -> RenderOutput:
        """Radiance, z-depth (metres) and triangle ids ``(H, W)`` from pose ``T_wc`` ``(4, 4)``.

        With supersampling, depth and ids come from one extra ray through each pixel centre."""
        view1 = self._view(1)
        hit = self._cast(view1, T_wc)
        rad = self._shade(view1, hit) if self.supersample == 1 else self.radiance(T_wc)
        H, W = self.camera.height, self.camera.width
        t_hit, ids = hit[0].reshape(H, W), hit[1].reshape(H, W)
        valid = np.isfinite(t_hit)
        depth = np.where(valid, t_hit, 0.0).astype(np.float32)
        tri = np.where(valid, ids.astype(np.int64), -1)
        return RenderOutput(radiance=rad, depth=depth, triangle_ids=tri)

    def radiance_at(self, t: float) -> np.ndarray:
        """Radiance ``(H, W)`` at recording time ``t`` (seconds): ``radiance(trajectory.pose(t))``."""
        return self.radiance(self.scene.trajectory.pose(float(t)))

    # -- internals -------------------------------------------------------------------------
    def _view(self, s: int) -> _View:
        if s not in self._views:
            cam = self.camera if s == 1 else self.camera.scaled(s)
            rays = cam.pixel_rays().reshape(-1, 3).astype(np.float32)  # z = 1: t_hit is z-depth
            inv_norm = (1.0 / np.linalg.norm(rays, axis=1)).astype(np.float32)
            f = np.sqrt(cam.fx * cam.fy)
            buf = np.empty((len(rays), 6), np.float32)
            tmp = np.empty(len(rays), np.float32)
            self._views[s] = _View(cam, rays, inv_norm, np.float32(np.log2(f)), buf, tmp)
        return self._views[s]

    def _cast(self, view: _View, T_wc: np.ndarray) -> tuple[np.ndarray, ...]:
        T = np.asarray(T_wc, np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"T_wc: expected a (4, 4) pose, got shape {T.shape}")
        R = T[:3, :3].astype(np.float32)
        buf = view.buf
        buf[:, :3] = T[:3, 3].astype(np.float32)
        # element-wise rather than matmul: BLAS threads spin against open3d's and slow both down
        x, y = view.rays[:, 0], view.rays[:, 1]
        for j in range(3):
            np.multiply(x, R[j, 0], out=view.tmp)
            view.tmp += R[j, 2]
            view.tmp += y * R[j, 1]
            buf[:, 3 + j] = view.tmp
        ans = self._rc.cast_rays(self._o3c.Tensor.from_numpy(buf))
        t_hit = ans["t_hit"].numpy()
        ids = ans["primitive_ids"].numpy()
        bary = ans["primitive_uvs"].numpy()
        normals = ans["primitive_normals"].numpy()
        return t_hit, ids, bary, normals, buf[:, 3:]

    def _shade(self, view: _View, hit: tuple[np.ndarray, ...]) -> np.ndarray:
        cam = view.camera
        if self.backend == "numba":
            t_hit, ids, bary, normals, dirs = hit
            a = self._atlas
            out = np.empty(len(t_hit), np.float32)
            _shade_kernel(
                t_hit, ids, bary, normals, dirs, view.inv_norm, view.log2_f,
                self._uv0, self._e1, self._e2, self._tex, self._level0, self._max_level, self._gain,
                a.texels, a.offset, a.width, a.height, a.scale_u, a.scale_v,
                self._min_cos, self.radiance_floor, out,
            )  # fmt: skip
            return out.reshape(cam.height, cam.width)
        return self._shade_numpy(view, hit)

    def _shade_numpy(self, view: _View, hit: tuple[np.ndarray, ...]) -> np.ndarray:
        t_hit, ids, bary, normals, dirs = hit
        n_rays = len(t_hit)
        out = np.full(n_rays, self.radiance_floor, np.float32)
        valid = np.isfinite(t_hit)
        all_valid = bool(valid.all())
        if not all_valid:
            t_hit, ids, bary, normals, dirs = (
                t_hit[valid],
                ids[valid],
                bary[valid],
                normals[valid],
                dirs[valid],
            )
            inv_norm = view.inv_norm[valid]
        else:
            inv_norm = view.inv_norm
        if len(t_hit):
            tid = ids.astype(np.int64)
            b1, b2 = bary[:, 0:1], bary[:, 1:2]
            uv = self._uv0[tid] + b1 * self._e1[tid] + b2 * self._e2[tid]
            cos = np.abs(np.einsum("ij,ij->i", normals, dirs)) * inv_norm
            np.maximum(cos, self._min_cos, out=cos)
            level = self._level0[tid] + np.log2(t_hit / cos) - view.log2_f
            np.clip(level, 0.0, self._max_level[tid], out=level)
            val = _trilinear(self._atlas, self._tex[tid], uv[:, 0], uv[:, 1], level)
            val *= self._gain[tid]
            if all_valid:
                out = val
            else:
                out[valid] = val
            np.maximum(out, self.radiance_floor, out=out)
        cam = view.camera
        return out.reshape(cam.height, cam.width)


@dataclass
class _View:
    camera: Camera
    rays: np.ndarray  # (N, 3) float32 camera-frame directions with z = 1
    inv_norm: np.ndarray  # (N,) float32 1 / |ray|
    log2_f: np.float32
    buf: np.ndarray  # (N, 6) float32 ray buffer handed to open3d
    tmp: np.ndarray  # (N,) float32 scratch


def _bilinear(
    atlas: TextureAtlas, tex: np.ndarray, lvl: np.ndarray, u: np.ndarray, v: np.ndarray
) -> np.ndarray:
    """Bilinear, wrapping lookup at integer mip level ``lvl`` of level-0 texel coords ``(u, v)``."""
    w = atlas.width[tex, lvl]
    h = atlas.height[tex, lvl]
    off = atlas.offset[tex, lvl]
    x = u * atlas.scale_u[tex, lvl] - 0.5
    y = v * atlas.scale_v[tex, lvl] - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0).astype(np.float32)
    fy = (y - y0).astype(np.float32)
    wm, hm = w - 1, h - 1  # sides are powers of two: wrap with a bit mask
    xi = x0.astype(np.int64)
    yi = y0.astype(np.int64)
    xa, xb = xi & wm, (xi + 1) & wm
    ra, rb = off + (yi & hm) * w, off + ((yi + 1) & hm) * w
    t = atlas.texels
    top = t[ra + xa] + fx * (t[ra + xb] - t[ra + xa])
    bot = t[rb + xa] + fx * (t[rb + xb] - t[rb + xa])
    return top + fy * (bot - top)


def _trilinear(
    atlas: TextureAtlas, tex: np.ndarray, u: np.ndarray, v: np.ndarray, level: np.ndarray
) -> np.ndarray:
    """Trilinear (mip-mapped) lookup: bilinear at the two mip levels around ``level``, blended."""
    l0 = np.floor(level).astype(np.int64)
    frac = (level - l0).astype(np.float32)
    a = _bilinear(atlas, tex, l0, u, v)
    if not np.any(frac > 0):
        return a
    b = _bilinear(atlas, tex, l0 + 1, u, v)
    # l0 + 1 may exceed a texture's last level only where frac == 0 (level clipped to the maximum)
    return a + frac * (b - a)


if HAVE_NUMBA:

    @numba.njit(cache=True, nogil=True, fastmath=False)
    def _shade_kernel(
        t_hit, ids, bary, normals, dirs, inv_norm, log2_f,
        uv0, e1, e2, tex_of, level0, max_level, gain,
        texels, offset, width, height, scale_u, scale_v,
        min_cos, floor, out,
    ):  # fmt: skip
        """Fused per-ray version of :meth:`Renderer._shade_numpy` (same arithmetic, float32)."""
        for i in range(t_hit.shape[0]):
            t = t_hit[i]
            if not np.isfinite(t):
                out[i] = floor
                continue
            k = ids[i]
            b1 = bary[i, 0]
            b2 = bary[i, 1]
            u = uv0[k, 0] + b1 * e1[k, 0] + b2 * e2[k, 0]
            v = uv0[k, 1] + b1 * e1[k, 1] + b2 * e2[k, 1]
            c = abs(
                normals[i, 0] * dirs[i, 0] + normals[i, 1] * dirs[i, 1] + normals[i, 2] * dirs[i, 2]
            )
            c = max(c * inv_norm[i], min_cos)
            level = level0[k] + np.log2(np.float32(t / c)) - log2_f
            level = min(max(level, np.float32(0.0)), max_level[k])
            tx = tex_of[k]
            l0 = int(np.floor(level))
            frac = level - np.float32(l0)
            val = np.float32(0.0)
            for j in range(2):
                lv = l0 + j
                wgt = (np.float32(1.0) - frac) if j == 0 else frac
                if j == 1 and frac == 0:
                    break
                w = width[tx, lv]
                h = height[tx, lv]
                off = offset[tx, lv]
                x = u * scale_u[tx, lv] - np.float32(0.5)
                y = v * scale_v[tx, lv] - np.float32(0.5)
                xf = np.floor(x)
                yf = np.floor(y)
                fx = x - xf
                fy = y - yf
                xi = int(xf)
                yi = int(yf)
                xa = xi & (w - 1)
                xb = (xi + 1) & (w - 1)
                ra = off + (yi & (h - 1)) * w
                rb = off + ((yi + 1) & (h - 1)) * w
                top = texels[ra + xa] + fx * (texels[ra + xb] - texels[ra + xa])
                bot = texels[rb + xa] + fx * (texels[rb + xb] - texels[rb + xa])
                val += wgt * (top + fy * (bot - top))
            out[i] = max(val * gain[k], floor)
