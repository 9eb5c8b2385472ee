"""PatchMatch multi-view stereo in PyTorch: one depth and normal map per reference view.

The method is PatchMatch stereo with slanted support windows (Bleyer et al., BMVC 2011) in its
multi-view form (Galliani et al., ICCV 2015; Schoenberger et al., ECCV 2016): every pixel holds a
plane hypothesis (z-depth and camera-frame normal); a hypothesis is scored by a bilaterally
weighted normalised cross-correlation (NCC) between the reference window and its plane-induced
warp into each source view, and the per-view costs (1 - NCC, in [0, 2]) are averaged over the best
views. Pixels of one colour of a red-black checkerboard are updated in parallel: each tries the
planes of its best neighbour in four directions (plane propagation) and random perturbations of
its own plane. Coarse-to-fine: the first scales run on downsampled images. An optional second
pass adds a geometric-consistency term (forward-backward reprojection error against the source
views' depth maps).

Efficiency notes (all tensors on one device, float32):
- the window warp uses the homography's first-order (affine) expansion about the window centre,
  whose error is a small fraction of a pixel for windows of a few pixels (the centre is exact);
  with it, the sample coordinates of a whole chunk are one small matrix product;
- all source images live in one atlas image so that one ``grid_sample`` call samples every view;
- on the CPU pixels are processed in chunks whose working set stays in the cache.

Conventions: pixel centres at integer coordinates; ``K`` is the 3x3 intrinsic matrix (no skew);
``R, t`` map world to camera (``X_cam = R X_world + t``); depth is the camera-frame z; normals are
unit vectors in the reference camera frame, oriented towards the camera (``n . ray < 0``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from evdense.log import get_logger

log = get_logger("mvs")

MAX_COST = 2.0  # cost of an invalid hypothesis (1 - NCC lies in [0, 2])


# --------------------------------------------------------------------------------------------
# inputs, outputs, settings
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StereoView:
    """One calibrated view.

    ``image``: ``(H, W)`` float32 grey levels in [0, 1]; ``K``: ``(3, 3)`` intrinsics in pixels
    (pixel centres at integer coordinates); ``R`` ``(3, 3)`` and ``t`` ``(3,)``: world-to-camera.
    """

    image: np.ndarray
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, ``(3,)``."""
        return -np.asarray(self.R, np.float64).T @ np.asarray(self.t, np.float64)

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.image.shape[0]), int(self.image.shape[1])


@dataclass
class DepthNormalMap:
    """A depth map ``(H, W)`` (z-depth, 0 = invalid), normal map ``(H, W, 3)`` (camera frame) and
    aggregated matching cost ``(H, W)`` (1 - NCC in [0, 2]; 2 = no valid match)."""

    depth: np.ndarray
    normal: np.ndarray
    cost: np.ndarray

    @classmethod
    def empty(cls, height: int, width: int) -> DepthNormalMap:
        return cls(
            depth=np.zeros((height, width), np.float32),
            normal=np.zeros((height, width, 3), np.float32),
            cost=np.full((height, width), MAX_COST, np.float32),
        )

    @property
    def valid_fraction(self) -> float:
        return float((self.depth > 0).mean())


@dataclass
class PatchMatchConfig:
    """Settings of the PatchMatch depth and normal estimation for one reference view."""

    iterations: list[int] = field(default_factory=lambda: [4, 2, 1])
    """Iterations per scale, coarsest first; the list length is the number of scales (each scale
    halves the resolution of the next). One iteration updates both checkerboard colours."""
    min_scale_size: int = 48
    """Scales whose smaller image side would fall below this many pixels are skipped; their
    iterations run at the coarsest kept scale."""
    window_radius: int = 4
    """Half size of the matching window, pixels (the same at every scale)."""
    window_step: int = 2
    """Spacing between the window's samples, pixels."""
    window_sparse: bool = True
    """Keep only the window samples of one checkerboard colour (about half the cost)."""
    exact_warp: bool = False
    """Warp every window sample with the exact plane-induced homography (slower); default: its
    first-order expansion about the window centre (exact at the centre)."""
    sigma_spatial: float = 4.0
    """Spatial sigma of the bilateral window weights, pixels."""
    sigma_color: float = 0.1
    """Intensity sigma of the bilateral window weights (grey levels in [0, 1])."""
    min_texture_std: float = 0.004
    """Pixels whose weighted window standard deviation (grey levels in [0, 1]) is below this are
    left unmatched."""
    num_best_views: int = 0
    """Number of best per-view costs averaged per pixel; 0 = half the source views (at least 1)."""
    propagation_distances: list[int] = field(default_factory=lambda: [1, 3, 5])
    """Odd neighbour distances (pixels) searched in each of the 4 directions; the neighbour with the
    lowest cost per direction is propagated."""
    depth_perturbation: float = 0.1
    """Relative depth perturbation (log scale) of the first refinement, halved every iteration."""
    normal_perturbation: float = 0.4
    """Normal perturbation (std of a random tilt, ~radians) of the first refinement, halved every
    iteration."""
    min_perturbation_scale: float = 0.05
    """The halving of the perturbations stops at this fraction of their initial values."""
    max_slant_deg: float = 80.0
    """Largest angle between a hypothesis' normal and the viewing ray, degrees."""
    geom_weight: float = 0.3
    """Weight of the geometric term (forward-backward reprojection error, pixels) in the cost."""
    geom_max_error: float = 3.0
    """The forward-backward reprojection error is capped at this many pixels in the cost."""
    geom_iterations: int = 1
    """Iterations of the geometric-consistency pass at full resolution (0 = filter only)."""
    chunk_size: int = 0
    """Pixels evaluated at once; 0 = 2048 on the CPU (cache-sized), 262144 on CUDA."""
    seed: int = 0
    """Seed of the random initialisation and perturbations (plus the view index)."""

    def check(self) -> None:
        if not self.iterations or any(int(i) < 0 for i in self.iterations):
            raise ValueError(
                f"mvs.patch_match.iterations must be a non-empty list of >= 0 integers, got {self.iterations}"
            )
        if self.window_radius < 1 or self.window_step < 1:
            raise ValueError("mvs.patch_match.window_radius and window_step must be >= 1")
        if any(d < 1 or d % 2 == 0 for d in self.propagation_distances):
            raise ValueError(
                f"mvs.patch_match.propagation_distances must be odd and >= 1 (checkerboard), got {self.propagation_distances}"
            )


@dataclass
class FilterConfig:
    """Which depth-map pixels are kept (invalid pixels get depth 0)."""

    max_cost: float = 0.5
    """Largest aggregated cost (1 - NCC) of a kept pixel."""
    min_consistent_views: int = 1
    """Least number of source views whose depth map agrees (geometric consistency); used when the
    source views' depth maps are given."""
    max_reprojection_error: float = 1.0
    """Forward-backward reprojection error below which a source view agrees, pixels."""
    max_relative_depth_error: float = 0.01
    """Relative depth difference below which a source view agrees."""
    min_triangulation_angle: float = 1.0
    """Least triangulation angle between the reference and an agreeing (or, without source depth
    maps, a seeing) source view, degrees."""


def resolve_device(name: str = "auto") -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; otherwise ``torch.device(name)``."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


# --------------------------------------------------------------------------------------------
# one scale of one reference view
# --------------------------------------------------------------------------------------------
def _scaled_K(K: np.ndarray, sx: float, sy: float) -> np.ndarray:
    """Intrinsics of an image resampled by ``(sx, sy)`` (pixel centres at integer coordinates)."""
    Ks = np.array(K, np.float64).copy()
    Ks[0, 0] *= sx
    Ks[1, 1] *= sy
    Ks[0, 2] = (Ks[0, 2] + 0.5) * sx - 0.5
    Ks[1, 2] = (Ks[1, 2] + 0.5) * sy - 0.5
    return Ks


def _resize(img: torch.Tensor, h: int, w: int) -> torch.Tensor:
    if img.shape[-2:] == (h, w):
        return img
    return F.interpolate(img[None, None], size=(h, w), mode="area")[0, 0]


class _Scale:
    """Everything needed to score hypotheses of one reference view at one resolution."""

    # Over 80 lines on purpose: a straight-line set-up of every tensor the scoring kernels of one
    # scale read (reference image and pixel rays, the sources' image atlas and projections, their
    # depth atlas, window offsets); no branch worth a function.
    def __init__(
        self,
        ref: StereoView,
        sources: Sequence[StereoView],
        factor: float,
        cfg: PatchMatchConfig,
        device: torch.device,
        source_depths: Sequence[np.ndarray | None] | None,
    ):
        H0, W0 = ref.shape
        self.H = H = max(8, int(round(H0 * factor)))
        self.W = W = max(8, int(round(W0 * factor)))
        self.device = device
        dt = torch.float32
        f64 = dict(dtype=torch.float64, device=device)

        Kr = _scaled_K(ref.K, W / W0, H / H0)
        self.K = torch.tensor(Kr, **f64)
        self.fx, self.fy = float(Kr[0, 0]), float(Kr[1, 1])
        Kr_inv = np.linalg.inv(Kr)
        self.ref = _resize(torch.as_tensor(ref.image, dtype=dt, device=device), H, W).contiguous()

        ys, xs = torch.meshgrid(
            torch.arange(H, device=device), torch.arange(W, device=device), indexing="ij"
        )
        pix = torch.stack(
            [xs.reshape(-1), ys.reshape(-1), torch.ones(H * W, dtype=torch.long, device=device)], 1
        )
        self.pix = pix.to(dt)  # (HW, 3) homogeneous pixel centres
        self.rays = (self.pix.double() @ torch.tensor(Kr_inv.T, **f64)).to(dt)  # (HW, 3), z = 1
        self.ys, self.xs = ys.reshape(-1), xs.reshape(-1)

        # --- source atlas: all source images stacked vertically with a blank gap between them ---
        V = len(sources)
        self.V = V
        sizes = []
        imgs = []
        for s in sources:
            h0, w0 = s.shape
            h, w = max(8, int(round(h0 * factor))), max(8, int(round(w0 * factor)))
            sizes.append((h, w, w / w0, h / h0))
            imgs.append(_resize(torch.as_tensor(s.image, dtype=dt, device=device), h, w))
        gap = 2 * cfg.window_radius + 4
        Hm = max(h for h, _, _, _ in sizes)
        Wa = max(w for _, w, _, _ in sizes)
        Ha = V * Hm + (V - 1) * gap
        atlas = torch.zeros(Ha, Wa, dtype=dt, device=device)
        offs = [v * (Hm + gap) for v in range(V)]
        for v, im in enumerate(imgs):
            atlas[offs[v] : offs[v] + im.shape[0], : im.shape[1]] = im
        self.atlas = atlas[None, None]
        self.Ha, self.Wa, self.offs = Ha, Wa, offs

        Rr, tr = np.asarray(ref.R, np.float64), np.asarray(ref.t, np.float64)
        A, b, lo, hi, Kv_inv, Rrel, trel = [], [], [], [], [], [], []
        for v, s in enumerate(sources):
            h, w, sx, sy = sizes[v]
            Kv = _scaled_K(s.K, sx, sy)
            R_rel = np.asarray(s.R, np.float64) @ Rr.T
            t_rel = np.asarray(s.t, np.float64) - R_rel @ tr
            Nv = np.array(
                [
                    [2.0 / (Wa - 1), 0, -1.0],
                    [0, 2.0 / (Ha - 1), 2.0 * offs[v] / (Ha - 1) - 1.0],
                    [0, 0, 1.0],
                ]
            )
            A.append(Nv @ Kv @ R_rel @ Kr_inv)
            b.append(Nv @ Kv @ t_rel)
            lo.append(Nv @ np.array([0.0, 0.0, 1.0]))
            hi.append(Nv @ np.array([w - 1.0, h - 1.0, 1.0]))
            Kv_inv.append(np.linalg.inv(Kv))
            Rrel.append(R_rel)
            trel.append(t_rel)
        self.A = torch.tensor(np.array(A), **f64).to(dt)  # (V, 3, 3)
        self.b = torch.tensor(np.array(b), **f64).to(dt)  # (V, 3)
        self.lo = torch.tensor(np.array(lo)[:, :2], **f64).to(dt)  # (V, 2) normalised bounds
        self.hi = torch.tensor(np.array(hi)[:, :2], **f64).to(dt)
        self.Kv_inv = torch.tensor(np.array(Kv_inv), **f64).to(dt)
        self.Rrel = torch.tensor(np.array(Rrel), **f64).to(dt)
        self.trel = torch.tensor(np.array(trel), **f64).to(dt)
        # source camera centres in the reference frame (for triangulation angles)
        self.src_centers = torch.tensor(
            np.array([-R.T @ t for R, t in zip(Rrel, trel, strict=True)]), **f64
        ).to(dt)
        self.off_t = torch.tensor(offs, dtype=dt, device=device)
        self.A2 = self.A[:, :, :2, None].contiguous()  # (V, 3, 2, 1)
        self.mid = ((self.lo + self.hi) / 2)[:, :, None]  # (V, 2, 1)
        self.half = ((self.hi - self.lo) / 2)[:, :, None]
        self.inv_f = torch.tensor([[1.0 / self.fx], [1.0 / self.fy]], dtype=dt, device=device)
        self.min_var = cfg.min_texture_std**2

        # --- source depth maps (geometric consistency), in the same atlas layout ---
        self.depth_atlas = None
        if source_depths is not None and any(d is not None for d in source_depths):
            da = torch.zeros(Ha, Wa, dtype=dt, device=device)
            for v, d in enumerate(source_depths):
                if d is None:
                    continue
                h, w = sizes[v][:2]
                dv = torch.as_tensor(np.asarray(d, np.float32), device=device)
                if dv.shape != (h, w):  # nearest: never mix depths across an edge
                    dv = F.interpolate(dv[None, None], size=(h, w), mode="nearest")[0, 0]
                da[offs[v] : offs[v] + h, :w] = dv
            self.depth_atlas = da[None, None]

        # --- matching window ---
        r, st = cfg.window_radius, cfg.window_step
        offsets = [
            (ox, oy)
            for oy in range(-r, r + 1, st)
            for ox in range(-r, r + 1, st)
            if not cfg.window_sparse or ((ox // st + oy // st) % 2 == 0)
        ]
        self.S = len(offsets)
        off = torch.tensor(offsets, dtype=dt, device=device)  # (S, 2)
        self.O = torch.cat(
            [torch.ones(self.S, 1, dtype=dt, device=device), off], 1
        )  # (S, 3): [1, ox, oy]
        pad = r
        ref_pad = F.pad(self.ref[None, None], (pad, pad, pad, pad), mode="reflect")[0, 0]
        self.ref_pad, self.pad = ref_pad, pad
        self.win_flat = off[:, 1].long() * (W + 2 * pad) + off[:, 0].long()  # (S,)
        self.win_sq = (off**2).sum(1)  # (S,)
        self.cfg = cfg
        self.chunk = cfg.chunk_size or (4096 if device.type == "cpu" else 262144)

        self._colors: list[_ColorData] | None = None

    @property
    def colors(self) -> list[_ColorData]:
        """The two checkerboard colours: their chunks (window statistics) and propagation
        neighbours, built on first use (the filter needs none of it)."""
        if self._colors is None:
            cb = ((self.ys + self.xs) % 2).reshape(-1)
            self._colors = [
                _ColorData(self, torch.nonzero(cb == c).squeeze(1), self.cfg) for c in (0, 1)
            ]
        return self._colors

    # ---------------------------------------------------------------- window statistics
    def window_stats(self, idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Bilateral weights ``(S, n)``, weighted centred reference values times weights ``(S, n)``
        and the weighted variance ``(n,)`` of the windows of pixels ``idx``."""
        cfg = self.cfg
        y, x = self.ys[idx], self.xs[idx]
        base = (y + self.pad) * (self.W + 2 * self.pad) + (x + self.pad)
        vals = self.ref_pad.reshape(-1)[base[None, :] + self.win_flat[:, None]]  # (S, n)
        centre = self.ref.reshape(-1)[idx]
        wt = torch.exp(
            -self.win_sq[:, None] / (2 * cfg.sigma_spatial**2)
            - (vals - centre[None]) ** 2 / (2 * cfg.sigma_color**2)
        )
        wt = wt / wt.sum(0, keepdim=True)
        mean = (wt * vals).sum(0)
        dev = vals - mean[None]
        var = (wt * dev * dev).sum(0)
        return wt.contiguous(), (wt * dev).contiguous(), var

    # ---------------------------------------------------------------- scoring
    def score(
        self, ch: _Chunk, d: torch.Tensor, nrm: torch.Tensor, k: int, geom: bool
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Aggregated cost ``(n,)`` of the hypotheses ``d`` ``(n,)``, ``nrm`` ``(n, 3)`` of a chunk,
        and its photometric part (the same tensor unless ``geom``)."""
        n, V, S = d.shape[0], self.V, self.S
        delta = d * (nrm * ch.rays).sum(1)  # n . X_p: the plane is n . X = delta (negative)
        g = nrm[:, :2].T / delta[None] * self.inv_f  # (2, n): derivative of 1/z w.r.t. the offset
        # homogeneous warp of the window centre h0 and its derivative G w.r.t. the offset
        h0 = torch.addcmul(ch.Ap, self.b[:, :, None], (1.0 / d)[None, None])  # (V, 3, n)
        G = torch.addcmul(self.A2, self.b[:, :, None, None], g[None, None])  # (V, 3, 2, n)
        hz = h0[:, 2]
        inv_hz = 1.0 / torch.where(hz > 1e-6, hz, torch.ones_like(hz))
        c = h0[:, :2] * inv_hz[:, None]  # (V, 2, n) normalised atlas coordinates of the centre
        if self.cfg.exact_warp:  # the homography at every window sample
            M = torch.empty(V, 3, 3, n, dtype=d.dtype, device=d.device)  # rows x y z: [h0, G]
            M[:, :, 0] = h0
            M[:, :, 1:] = G
            hom = (self.O @ M.permute(2, 0, 3, 1).reshape(3, V * n * 3)).reshape(S, V, n, 3)
            z = hom[..., 2:3]
            grid = (hom[..., :2] / torch.where(z > 1e-6, z, torch.ones_like(z))).reshape(
                1, S, V * n, 2
            )
        else:  # its first-order expansion about the window centre: one small matrix product
            M = torch.empty(V, 2, 3, n, dtype=d.dtype, device=d.device)  # [centre, d/dox, d/doy]
            M[:, :, 0] = c
            torch.addcmul(G[:, :2], c[:, :, None], G[:, 2:3], value=-1.0, out=M[:, :, 1:])
            M[:, :, 1:] *= inv_hz[:, None, None]
            T = M.permute(2, 0, 3, 1).reshape(3, V * n * 2)
            grid = (self.O @ T).reshape(1, S, V * n, 2)
        vals = F.grid_sample(
            self.atlas, grid, mode="bilinear", padding_mode="zeros", align_corners=True
        )
        vals = vals.reshape(S, V, n)
        jw = vals * ch.wt[:, None]
        s_j = jw.sum(0)
        s_jj = (jw * vals).sum(0)
        s_ij = (vals * ch.iw[:, None]).sum(0)
        var_j = s_jj - s_j * s_j  # (V, n)
        ncc = s_ij * torch.rsqrt((var_j * ch.var[None]).clamp_min(1e-12))
        inside = ((c - self.mid).abs() <= self.half).all(1) & (hz > 1e-6)
        ok = inside & (var_j > self.min_var) & ch.textured[None]
        cost = torch.where(ok, (1.0 - ncc).clamp(0.0, MAX_COST), MAX_COST)
        photo = _mean_of_smallest(cost, k)
        if geom and self.depth_atlas is not None:
            err = self.fb_error(c.permute(2, 0, 1), d, ch.rays, ch.pix).T
            total = cost + self.cfg.geom_weight * err.clamp_max(self.cfg.geom_max_error)
            return _mean_of_smallest(total, k), photo
        return photo, photo

    def fb_error(
        self, c: torch.Tensor, d: torch.Tensor, rays: torch.Tensor, pix: torch.Tensor
    ) -> torch.Tensor:
        """Forward-backward reprojection error ``(n, V)`` in pixels of the points ``d * rays``
        projected to ``c`` (normalised atlas coordinates) in each source view; inf where the
        source depth is missing or the point falls outside."""
        n, V = c.shape[:2]
        ds = F.grid_sample(
            self.depth_atlas,
            c.reshape(1, 1, n * V, 2),
            mode="nearest",
            padding_mode="zeros",
            align_corners=True,
        ).reshape(n, V)
        u = (c[..., 0] + 1) * (self.Wa - 1) / 2
        v = (c[..., 1] + 1) * (self.Ha - 1) / 2 - self.off_t[None]
        ph = torch.stack([u, v, torch.ones_like(u)], -1)  # (n, V, 3) source pixel, homogeneous
        Xs = torch.einsum("vij,nvj->nvi", self.Kv_inv, ph) * ds[..., None]
        Xr = torch.einsum("vji,nvj->nvi", self.Rrel, Xs - self.trel[None])  # R_rel^T (Xs - t_rel)
        z = Xr[..., 2]
        z_safe = torch.where(z > 1e-6, z, torch.ones_like(z))
        pu = self.K[0, 0].float() * Xr[..., 0] / z_safe + self.K[0, 2].float()
        pv = self.K[1, 1].float() * Xr[..., 1] / z_safe + self.K[1, 2].float()
        err = torch.sqrt((pu - pix[:, None, 0]) ** 2 + (pv - pix[:, None, 1]) ** 2)
        bad = (ds <= 0) | (z <= 1e-6) | ~torch.isfinite(err)
        return torch.where(bad, torch.full_like(err, float("inf")), err)


def _mean_of_smallest(cost: torch.Tensor, k: int) -> torch.Tensor:
    """Mean of the ``k`` smallest rows of ``cost`` ``(V, n)`` -> ``(n,)`` (partial bubble sort on
    rows: cheaper than topk for a handful of views)."""
    V = cost.shape[0]
    if k >= V:
        return cost.mean(0)
    if k == 1:
        return cost.amin(0)
    rows = list(cost.unbind(0))
    total = None
    for i in range(k):
        for j in range(V - 1, i, -1):
            lo_, hi_ = torch.minimum(rows[j - 1], rows[j]), torch.maximum(rows[j - 1], rows[j])
            rows[j - 1], rows[j] = lo_, hi_
        total = rows[i] if total is None else total + rows[i]
    return total / k


class _Chunk:
    """Per-pixel data of a chunk of one checkerboard colour, constant over the iterations."""

    def __init__(self, sc: _Scale, idx: torch.Tensor, cfg: PatchMatchConfig):
        self.idx = idx
        self.rays = sc.rays[idx]
        self.pix = sc.pix[idx]
        self.wt, self.iw, self.var = sc.window_stats(idx)
        self.textured = self.var > cfg.min_texture_std**2
        self.Ap = torch.einsum("vij,nj->vin", sc.A, self.pix).contiguous()  # (V, 3, n)


class _ColorData:
    """Pixels of one checkerboard colour: chunks and propagation neighbours."""

    def __init__(self, sc: _Scale, idx: torch.Tensor, cfg: PatchMatchConfig):
        self.idx = idx
        self.chunks = [_Chunk(sc, idx[a : a + sc.chunk], cfg) for a in range(0, len(idx), sc.chunk)]
        y, x = sc.ys[idx], sc.xs[idx]
        dists = torch.tensor(cfg.propagation_distances, device=sc.device)
        self.neighbours = []  # per direction: flat indices (ndist, n) and in-bounds mask
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            ny = y[None] + dy * dists[:, None]
            nx = x[None] + dx * dists[:, None]
            ok = (ny >= 0) & (ny < sc.H) & (nx >= 0) & (nx < sc.W)
            flat = ny.clamp(0, sc.H - 1) * sc.W + nx.clamp(0, sc.W - 1)
            self.neighbours.append((flat, ok))


# --------------------------------------------------------------------------------------------
# hypotheses
# --------------------------------------------------------------------------------------------
def _face_camera(nrm: torch.Tensor, rays: torch.Tensor, max_slant_deg: float) -> torch.Tensor:
    """Flip normals to face the camera and tilt those beyond ``max_slant_deg`` back towards the ray."""
    rhat = rays / rays.norm(dim=-1, keepdim=True)
    dot = (nrm * rhat).sum(-1, keepdim=True)
    nrm = torch.where(dot > 0, -nrm, nrm)
    cos_min = math.cos(math.radians(max_slant_deg))
    dot = -(nrm * rhat).sum(-1, keepdim=True)  # cos(angle to -ray), >= 0
    # move along -rhat until the cosine reaches cos_min: n' = n - a * rhat
    tang = nrm + dot * rhat  # component orthogonal to the ray
    tn = tang.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    sin_min = math.sqrt(1 - cos_min**2)
    fixed = -cos_min * rhat + sin_min * tang / tn
    nrm = torch.where(dot < cos_min, fixed, nrm)
    return nrm / nrm.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def _random_normals(rays: torch.Tensor, gen: torch.Generator, max_slant_deg: float) -> torch.Tensor:
    u = torch.randn(rays.shape, generator=gen, device=rays.device, dtype=rays.dtype)
    rhat = rays / rays.norm(dim=-1, keepdim=True)
    # bias towards the camera: fronto-parallel-ish planes are the common case
    u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-12) - rhat
    return _face_camera(u, rays, max_slant_deg)


def _random_depths(
    n: int, lo: float, hi: float, gen: torch.Generator, device: torch.device
) -> torch.Tensor:
    """Depths uniform in inverse depth between ``lo`` and ``hi``."""
    u = torch.rand(n, generator=gen, device=device)
    return 1.0 / (1.0 / hi + u * (1.0 / lo - 1.0 / hi))


def _propagate_plane(
    d_q: torch.Tensor, n_q: torch.Tensor, r_q: torch.Tensor, r_p: torch.Tensor
) -> torch.Tensor:
    """Depth at ray ``r_p`` of the plane through ``d_q * r_q`` with normal ``n_q``."""
    num = d_q * (n_q * r_q).sum(-1)
    den = (n_q * r_p).sum(-1)
    d = num / torch.where(den < -1e-3, den, -torch.ones_like(den))
    return torch.where(den < -1e-3, d, d_q)


# --------------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------------
class _State:
    """Per-pixel hypotheses (flat): depth ``(n,)``, normal ``(n, 3)``, cost ``(n,)`` (the one
    minimised) and its photometric part ``photo`` ``(n,)``."""

    def __init__(self, depth: torch.Tensor, normal: torch.Tensor, cost: torch.Tensor):
        self.depth, self.normal, self.cost = depth, normal, cost
        self.photo = cost


def _evaluate_all(sc: _Scale, st: _State, k: int, geom: bool) -> None:
    st.photo = torch.empty_like(st.cost) if geom else st.cost
    for col in sc.colors:
        for ch in col.chunks:
            total, photo = sc.score(ch, st.depth[ch.idx], st.normal[ch.idx], k, geom)
            st.cost[ch.idx] = total
            if geom:
                st.photo[ch.idx] = photo


def _iterate(
    sc: _Scale,
    st: _State,
    k: int,
    geom: bool,
    depth_range: tuple[float, float],
    gen: torch.Generator,
    pert: float,
    with_random: bool,
) -> None:
    """One red-black iteration: propagation then refinement, for both colours."""
    cfg = sc.cfg
    lo, hi = depth_range
    for col in sc.colors:
        idx = col.idx
        n = idx.shape[0]
        r_p = sc.rays[idx]
        cand_d: list[torch.Tensor] = []
        cand_n: list[torch.Tensor] = []
        for flat, ok in col.neighbours:
            # the lowest-cost neighbour among the distances of this direction
            cst = torch.where(ok, st.cost[flat], float("inf"))
            q, best = flat[0], cst[0]
            for j in range(1, flat.shape[0]):
                better = cst[j] < best
                q = torch.where(better, flat[j], q)
                best = torch.where(better, cst[j], best)
            n_q = st.normal[q]
            d_p = _propagate_plane(st.depth[q], n_q, sc.rays[q], r_p).clamp(lo, hi)
            cand_d.append(d_p)
            cand_n.append(_face_camera(n_q, r_p, cfg.max_slant_deg))
        d0, n0 = st.depth[idx], st.normal[idx]
        sd = cfg.depth_perturbation * pert
        sn = cfg.normal_perturbation * pert
        eps = (torch.rand(n, generator=gen, device=sc.device) * 2 - 1) * sd
        d_pert = (d0 * torch.exp(eps)).clamp(lo, hi)
        n_pert = _face_camera(
            n0 + sn * torch.randn(n, 3, generator=gen, device=sc.device), r_p, cfg.max_slant_deg
        )
        cand_d += [d_pert, d0, d_pert]
        cand_n += [n_pert, n_pert, n0]
        if with_random:
            cand_d.append(_random_depths(n, lo, hi, gen, sc.device))
            cand_n.append(_random_normals(r_p, gen, cfg.max_slant_deg))
        D = torch.stack(cand_d)  # (C, n)
        N = torch.stack(cand_n)  # (C, n, 3)
        costs = torch.empty_like(D)
        photos = torch.empty_like(D) if geom else costs
        a = 0
        for ch in col.chunks:
            m = ch.idx.shape[0]
            for ci in range(D.shape[0]):
                total, photo = sc.score(ch, D[ci, a : a + m], N[ci, a : a + m], k, geom)
                costs[ci, a : a + m] = total
                if geom:
                    photos[ci, a : a + m] = photo
            a += m
        best_c, best_p, best_d, best_n = st.cost[idx], st.photo[idx], d0, n0
        for ci in range(D.shape[0]):
            better = costs[ci] < best_c
            best_c = torch.where(better, costs[ci], best_c)
            best_p = torch.where(better, photos[ci], best_p)
            best_d = torch.where(better, D[ci], best_d)
            best_n = torch.where(better[:, None], N[ci], best_n)
        st.depth[idx], st.normal[idx], st.cost[idx] = best_d, best_n, best_c
        if geom:
            st.photo[idx] = best_p


def _upsample(
    prev: _State, prev_sc: _Scale, sc: _Scale, depth_range: tuple[float, float]
) -> _State:
    """Carry planes from a coarser scale: nearest coarse pixel's plane, intersected with each ray."""
    xc = ((sc.xs.float() + 0.5) * prev_sc.W / sc.W - 0.5).round().long().clamp(0, prev_sc.W - 1)
    yc = ((sc.ys.float() + 0.5) * prev_sc.H / sc.H - 0.5).round().long().clamp(0, prev_sc.H - 1)
    q = yc * prev_sc.W + xc
    n_q = prev.normal[q]
    d = _propagate_plane(prev.depth[q], n_q, prev_sc.rays[q], sc.rays).clamp(*depth_range)
    nrm = _face_camera(n_q, sc.rays, sc.cfg.max_slant_deg)
    return _State(d, nrm, torch.full_like(d, MAX_COST))


def _overlapping_sources(
    ref: StereoView, sources: Sequence[StereoView], depth_range: tuple[float, float]
) -> list[int]:
    """Indices of the sources that see any part of the reference frustum within the depth range."""
    H, W = ref.shape
    us, vs = np.meshgrid(np.linspace(0, W - 1, 9), np.linspace(0, H - 1, 7))
    rays = np.stack([us.ravel(), vs.ravel(), np.ones(us.size)], 1) @ np.linalg.inv(ref.K).T
    depths = np.geomspace(depth_range[0], depth_range[1], 5)
    Xr = (rays[None] * depths[:, None, None]).reshape(-1, 3)
    Xw = (Xr - np.asarray(ref.t)) @ np.asarray(ref.R)  # R^T (X - t)
    keep = []
    for i, s in enumerate(sources):
        Xs = Xw @ np.asarray(s.R).T + np.asarray(s.t)
        z = Xs[:, 2]
        front = z > 1e-9
        uv = Xs[front, :2] / z[front, None] @ np.asarray(s.K)[:2, :2].T + np.asarray(s.K)[:2, 2]
        h, w = s.shape
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        if inside.any():
            keep.append(i)
    return keep


def _effective_iterations(cfg: PatchMatchConfig, min_side: int) -> list[int]:
    """``cfg.iterations`` without the scales smaller than ``cfg.min_scale_size`` (their iterations
    move to the coarsest kept scale)."""
    iters = [int(i) for i in cfg.iterations]
    while len(iters) > 1 and min_side * 0.5 ** (len(iters) - 1) < cfg.min_scale_size:
        iters = [iters[0] + iters[1], *iters[2:]]
    return iters


# Over 80 lines on purpose: the schedule of one depth map (checks, source choice, coarse-to-fine
# photometric iterations, then geometric-consistency iterations) over one _Scale at a time; the
# scoring and propagation are _Scale's and _State's.
def estimate_depth_map(
    ref: StereoView,
    sources: Sequence[StereoView],
    depth_range: tuple[float, float],
    config: PatchMatchConfig | None = None,
    init: DepthNormalMap | None = None,
    source_depths: Sequence[np.ndarray | None] | None = None,
    device: str | torch.device = "auto",
    name: str = "",
) -> DepthNormalMap:
    """Estimate the depth and normal map of ``ref`` from ``sources`` by PatchMatch stereo.

    ``depth_range``: ``(min, max)`` z-depth of the scene in the reference view (model units).
    Without ``init``: the photometric pass (random initialisation, coarse-to-fine over
    ``config.iterations``). With ``init`` (a previous map of this view) and ``source_depths``
    (one ``(H, W)`` depth map per source, 0 = unknown, or None): the geometric-consistency pass,
    ``config.geom_iterations`` iterations at full resolution whose cost adds the
    forward-backward reprojection error. Returns raw (unfiltered) maps at ``ref``'s resolution;
    an empty map (with a warning) when no source view overlaps the reference view.
    """
    cfg = config or PatchMatchConfig()
    cfg.check()
    H, W = ref.shape
    lo, hi = float(depth_range[0]), float(depth_range[1])
    if not (0 < lo < hi and math.isfinite(hi)):
        raise ValueError(f"{name or 'reference view'}: bad depth range {depth_range}")
    keep = _overlapping_sources(ref, sources, (lo, hi))
    if not keep:
        log.warning(
            "%s: no source view overlaps the reference view; empty depth map", name or "view"
        )
        return DepthNormalMap.empty(H, W)
    if len(keep) < len(sources):
        log.info(
            "%s: %d of %d source views do not overlap; dropped",
            name,
            len(sources) - len(keep),
            len(sources),
        )
    sources = [sources[i] for i in keep]
    if source_depths is not None:
        source_depths = [source_depths[i] for i in keep]
    dev = resolve_device(device) if isinstance(device, str) else device
    k = cfg.num_best_views or max(1, len(sources) // 2)
    k = min(k, len(sources))
    gen = torch.Generator(device=dev)
    gen.manual_seed(int(cfg.seed) & 0x7FFFFFFF)

    with torch.inference_mode():
        if init is None:
            iters = _effective_iterations(cfg, min(H, W))
            n_scales = len(iters)
            st: _State | None = None
            prev_sc: _Scale | None = None
            it_done = 0
            for level in range(n_scales - 1, -1, -1):
                sc = _Scale(ref, sources, 0.5**level, cfg, dev, None)
                if st is None:
                    n = sc.H * sc.W
                    d = _random_depths(n, lo, hi, gen, dev)
                    st = _State(
                        d,
                        _random_normals(sc.rays, gen, cfg.max_slant_deg),
                        torch.empty(n, device=dev),
                    )
                else:
                    st = _upsample(st, prev_sc, sc, (lo, hi))
                _evaluate_all(sc, st, k, geom=False)
                coarsest = level == n_scales - 1
                for _ in range(iters[n_scales - 1 - level]):
                    pert = max(0.5**it_done, cfg.min_perturbation_scale)
                    _iterate(sc, st, k, False, (lo, hi), gen, pert, with_random=coarsest)
                    it_done += 1
                prev_sc = sc
        else:
            sc = _Scale(ref, sources, 1.0, cfg, dev, source_depths)
            d0 = torch.as_tensor(init.depth.reshape(-1), dtype=torch.float32, device=dev)
            n0 = torch.as_tensor(init.normal.reshape(-1, 3), dtype=torch.float32, device=dev)
            missing = (d0 <= 0) | (n0.norm(dim=1) < 0.5)
            if missing.any():
                m = int(missing.sum())
                d0[missing] = _random_depths(m, lo, hi, gen, dev)
                n0[missing] = _random_normals(sc.rays[missing], gen, cfg.max_slant_deg)
            st = _State(
                d0.clamp(lo, hi), _face_camera(n0, sc.rays, cfg.max_slant_deg), torch.empty_like(d0)
            )
            geom = sc.depth_atlas is not None
            _evaluate_all(sc, st, k, geom=geom)
            start = 0.5 ** max(sum(cfg.iterations) - 1, 0)
            for i in range(cfg.geom_iterations):
                pert = max(start * 0.5**i, cfg.min_perturbation_scale)
                _iterate(sc, st, k, geom, (lo, hi), gen, pert, with_random=False)
        depth = st.depth.reshape(sc.H, sc.W)
        normal = st.normal.reshape(sc.H, sc.W, 3)
        cost = st.photo.reshape(sc.H, sc.W)  # the photometric part is what the filter thresholds
        depth = torch.where(cost < MAX_COST, depth, torch.zeros_like(depth))
        return DepthNormalMap(
            depth=depth.cpu().numpy().astype(np.float32),
            normal=normal.cpu().numpy().astype(np.float32),
            cost=cost.cpu().numpy().astype(np.float32),
        )


def filter_depth_map(
    ref: StereoView,
    sources: Sequence[StereoView],
    dmap: DepthNormalMap,
    config: FilterConfig | None = None,
    source_depths: Sequence[np.ndarray | None] | None = None,
    device: str | torch.device = "auto",
) -> tuple[DepthNormalMap, np.ndarray]:
    """Keep the pixels of ``dmap`` that pass the cost, geometric-consistency and
    triangulation-angle tests; returns the filtered map (invalid = depth 0, normal 0) and the
    number of agreeing source views per pixel ``(H, W)`` int (-1 where not checked)."""
    fc = config or FilterConfig()
    H, W = dmap.depth.shape
    dev = resolve_device(device) if isinstance(device, str) else device
    d = torch.as_tensor(dmap.depth.reshape(-1), dtype=torch.float32, device=dev)
    keep = (d > 0) & (torch.as_tensor(dmap.cost.reshape(-1), device=dev) <= fc.max_cost)
    counts = torch.full((H * W,), -1, dtype=torch.int32, device=dev)
    if sources:
        sc = _Scale(ref, sources, 1.0, PatchMatchConfig(iterations=[0]), dev, source_depths)
        idx = torch.nonzero(keep).squeeze(1)
        dd, rays, pix = d[idx], sc.rays[idx], sc.pix[idx]
        X = dd[:, None] * rays  # (n, 3) reference frame
        h = torch.einsum("vij,nj->nvi", sc.A, pix) + sc.b[None] / dd[:, None, None]
        hz = h[..., 2]
        c = h[..., :2] / torch.where(hz > 1e-6, hz, torch.ones_like(hz))[..., None]
        inside = (hz > 1e-6) & (c >= sc.lo[None]).all(-1) & (c <= sc.hi[None]).all(-1)
        # triangulation angle with each source
        a = X / X.norm(dim=1, keepdim=True)
        bvec = X[:, None, :] - sc.src_centers[None]
        cosang = (a[:, None, :] * bvec).sum(-1) / bvec.norm(dim=-1).clamp_min(1e-12)
        angle_ok = torch.rad2deg(torch.arccos(cosang.clamp(-1, 1))) >= fc.min_triangulation_angle
        if sc.depth_atlas is not None:
            err = sc.fb_error(c, dd, rays, pix)
            # relative depth agreement: the source's depth against the point's depth in that view
            ds = F.grid_sample(
                sc.depth_atlas,
                c.reshape(1, 1, -1, 2),
                mode="nearest",
                padding_mode="zeros",
                align_corners=True,
            ).reshape(c.shape[:2])
            z_src = torch.einsum("vij,nj->nvi", sc.Rrel, X)[..., 2] + sc.trel[None, :, 2]
            rel = (ds - z_src).abs() / z_src.abs().clamp_min(1e-9)
            agree = (
                inside & (err <= fc.max_reprojection_error) & (rel <= fc.max_relative_depth_error)
            )
            n_agree = agree.sum(1)
            ok = (n_agree >= fc.min_consistent_views) & (agree & angle_ok).any(1)
            counts[idx] = n_agree.int()
        else:
            ok = (inside & angle_ok).any(1)
        keep[idx] = ok
    keep_np = keep.reshape(H, W).cpu().numpy()
    out = DepthNormalMap(
        depth=np.where(keep_np, dmap.depth, 0).astype(np.float32),
        normal=np.where(keep_np[..., None], dmap.normal, 0).astype(np.float32),
        cost=dmap.cost.copy(),
    )
    return out, counts.reshape(H, W).cpu().numpy()
