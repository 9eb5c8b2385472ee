"""Photometric mesh refinement, in the spirit of Vu et al. (PAMI 2012).

For pairs of views ``(i, j)``, every pixel ``p`` of view ``i`` that sees the mesh is followed to
the surface: the point ``x`` where its ray meets the plane of the face it hits (a differentiable
function of that face's vertices), and ``x`` is reprojected into view ``j``. The image of ``j``
sampled there (``grid_sample``) is compared with image ``i`` by ZNCC over small windows of ``i``'s
pixel grid; the loss is the mean ``1 - ZNCC`` over textured, fully visible windows, plus a
Laplacian (umbrella) regulariser of the displacement from the input mesh (by default; or of the
surface itself). Vertices move along their normals (one unknown each), with Adam,
coarse to fine over an image pyramid. Which face each pixel hits, and which reprojections are
visible in ``j`` (ray casting with open3d), is refreshed every few iterations.

The refinement is bounded in time, and never returns a mesh that scores worse than its input:
the full-resolution photometric score of the input and of each level's result are measured and
the best one is kept.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as Fnn

from evdense.camera import Camera
from evdense.log import get_logger
from evdense.mesh.geometry import (
    camera_rays,
    edges_of,
    make_scene,
    project,
    raycast_view,
    vertex_normals,
)
from evdense.mesh.views import Views

log = get_logger("refine")


@dataclass
class RefineConfig:
    """Settings of the photometric refinement."""

    scales: list[float] = field(default_factory=lambda: [0.5, 1.0])
    """Image scales of the pyramid levels, coarse to fine."""
    iterations: int = 40
    """Gradient steps per level."""
    max_seconds: float = 600.0
    """Time budget of the whole refinement (seconds); levels stop early when it runs out."""
    window: int = 5
    """ZNCC window side, in pixels of the current level."""
    min_std: float = 0.01
    """Windows of the reference image with a smaller intensity standard deviation are ignored (textureless)."""
    laplacian_weight: float = 0.5
    """Weight of the squared umbrella Laplacian (in mean edge lengths) against the mean 1 - ZNCC."""
    regularizer: str = "displacement"
    """What the Laplacian smooths: ``displacement`` (the move from the input mesh: a surface
    with no photometric evidence stays where it is, corners included) or ``surface`` (the
    vertices themselves: also smooths the input's noise, and rounds its corners and edges)."""
    step: float = 0.05
    """Adam learning rate, in mean edge lengths per iteration."""
    pairs_per_view: int = 2
    """Partner views of each reference view."""
    min_angle: float = 5.0
    """Smallest triangulation angle of a pair at the scene centre (degrees)."""
    max_angle: float = 40.0
    """Largest triangulation angle of a pair at the scene centre (degrees)."""
    pairs_per_iteration: int = 8
    """Pairs in each gradient step (a random subset; all when fewer)."""
    refresh_every: int = 5
    """Iterations between ray-casting refreshes (faces hit, visibility)."""
    depth_tolerance: float = 0.01
    """Relative depth tolerance of the visibility test in the second view."""
    max_views: int = 40
    """Views used at most (evenly spaced through the list)."""
    seed: int = 0
    """Seed of the pair subsets."""


@dataclass
class RefineResult:
    """The refined vertices ``(V, 3)`` and the photometric scores (mean 1 - ZNCC, lower is better)
    at full resolution: of the input, after each level, and of the result returned."""

    vertices: np.ndarray
    score_input: float
    score_levels: list[float]
    score_output: float
    seconds: float


def select_pairs(views: Views, centre: np.ndarray, config: RefineConfig) -> list[tuple[int, int]]:
    """Up to ``pairs_per_view`` partners per reference view whose triangulation angle at ``centre``
    lies in ``[min_angle, max_angle]``, preferring angles near their middle, and whose optical axes
    differ by less than 60 degrees."""
    C = views.centers
    dirs = centre - C
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    axes = views.poses[:, :3, 2]
    ang = np.degrees(np.arccos(np.clip(dirs @ dirs.T, -1, 1)))
    axis_ang = np.degrees(np.arccos(np.clip(axes @ axes.T, -1, 1)))
    mid = 0.5 * (config.min_angle + config.max_angle)
    pairs = []
    for i in range(len(views)):
        ok = (ang[i] >= config.min_angle) & (ang[i] <= config.max_angle) & (axis_ang[i] < 60)
        ok[i] = False
        cand = np.nonzero(ok)[0]
        cand = cand[np.argsort(np.abs(ang[i, cand] - mid))][: config.pairs_per_view]
        pairs += [(i, int(j)) for j in cand]
    return pairs


def _grey_pyramid_level(img: np.ndarray, cam: Camera, scale: float) -> tuple[np.ndarray, Camera]:
    from skimage.transform import resize

    g = img.mean(axis=2) if img.ndim == 3 else img
    if scale == 1.0:
        return g.astype(np.float32), cam
    c = cam.scaled(scale)
    return resize(g, (c.height, c.width), anti_aliasing=True).astype(np.float32), c


class _Level:
    """Images, cameras and per-pair pixel sets at one pyramid level."""

    def __init__(
        self, views: Views, pairs: list[tuple[int, int]], scale: float, config: RefineConfig
    ):
        self.pairs = pairs
        self.config = config
        self.cams: list[Camera] = []
        self.images: list[torch.Tensor] = []
        self.grey: list[np.ndarray] = []
        used = sorted({k for p in pairs for k in p})
        self.used = used
        for i in range(len(views)):
            if i in used:
                g, c = _grey_pyramid_level(views.image(i), views.cameras[i], scale)
            else:
                g, c = np.zeros((1, 1), np.float32), views.cameras[i]
            self.cams.append(c)
            self.grey.append(g)
            self.images.append(torch.from_numpy(g)[None, None])
        self.poses = views.poses
        self.rays = {i: camera_rays(self.cams[i], self.poses[i])[1].reshape(-1, 3) for i in used}
        self.sel: dict[tuple[int, int], tuple] = {}

    def refresh(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        """Ray-cast every used view; keep, per pair, the pixels of ``i`` whose surface point is
        visible in ``j``."""
        scene = make_scene(vertices, faces)
        hits = {i: raycast_view(scene, self.cams[i], self.poses[i]) for i in self.used}
        self.sel = {}
        for i, j in self.pairs:
            h = hits[i]
            pix = np.nonzero(h.face.ravel() >= 0)[0]
            if len(pix) == 0:
                continue
            d = self.rays[i][pix]
            x = self.poses[i][:3, 3] + d * h.depth.ravel()[pix, None]
            uv, z = project(x, self.cams[j], self.poses[j])
            cj = self.cams[j]
            ui, vi = np.rint(uv[:, 0]), np.rint(uv[:, 1])
            ok = (z > 0) & (ui >= 0) & (vi >= 0) & (ui < cj.width) & (vi < cj.height)
            ok[ok] &= z[ok] <= hits[j].depth[vi[ok].astype(int), ui[ok].astype(int)] * (
                1 + self.config.depth_tolerance
            )
            pix, d = pix[ok], d[ok]
            if len(pix) < self.config.window**2:
                continue
            self.sel[(i, j)] = (
                torch.from_numpy(pix),
                torch.from_numpy(h.face.ravel()[pix]),
                torch.from_numpy(d),
                torch.from_numpy(self.grey[i].ravel()[pix].astype(np.float64)),
            )

    def pair_loss(self, V: torch.Tensor, F: torch.Tensor, i: int, j: int) -> torch.Tensor | None:
        """Mean ``1 - ZNCC`` over the valid windows of pair ``(i, j)`` (None when there is none)."""
        if (i, j) not in self.sel:
            return None
        pix, face, d, a_vals = self.sel[(i, j)]
        o = torch.as_tensor(self.poses[i][:3, 3])
        tri = V[F[face]]  # (P, 3, 3)
        n = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        den = (n * d).sum(1)
        den = torch.where(den.abs() < 1e-12, torch.full_like(den, 1e-12), den)
        t = (n * (tri[:, 0] - o)).sum(1) / den
        x = o + t[:, None] * d
        Tj = torch.as_tensor(self.poses[j])
        xc = (x - Tj[:3, 3]) @ Tj[:3, :3]
        cj = self.cams[j]
        z = xc[:, 2].clamp_min(1e-6)
        u = cj.fx * xc[:, 0] / z + cj.cx
        v = cj.fy * xc[:, 1] / z + cj.cy
        grid = torch.stack([2 * u / (cj.width - 1) - 1, 2 * v / (cj.height - 1) - 1], -1).float()
        b_vals = (
            Fnn.grid_sample(
                self.images[j],
                grid[None, None],
                mode="bilinear",
                padding_mode="border",
                align_corners=True,
            )
            .reshape(-1)
            .double()
        )
        ci = self.cams[i]
        HW = ci.height * ci.width
        zeros = torch.zeros(HW, dtype=torch.float64)
        A = zeros.index_put((pix,), a_vals).reshape(1, 1, ci.height, ci.width)
        B = zeros.index_put((pix,), b_vals).reshape(1, 1, ci.height, ci.width)
        M = zeros.index_put((pix,), torch.ones(len(pix), dtype=torch.float64)).reshape(
            1, 1, ci.height, ci.width
        )
        w = self.config.window

        def box(X: torch.Tensor) -> torch.Tensor:
            # Window means from an integral image (much faster than avg_pool2d on CPU).
            c = Fnn.pad(X, (1, 0, 1, 0)).cumsum(2).cumsum(3)
            return (c[..., w:, w:] - c[..., :-w, w:] - c[..., w:, :-w] + c[..., :-w, :-w]) / (w * w)

        m = box(M)
        full = m > 0.999
        if not bool(full.any()):
            return None
        mA, mB = box(A), box(B)
        vA = box(A * A) - mA * mA
        vB = box(B * B) - mB * mB
        cov = box(A * B) - mA * mB
        good = full & (vA > self.config.min_std**2)
        if not bool(good.any()):
            return None
        zncc = cov / torch.sqrt(vA.clamp_min(1e-12) * vB.clamp_min(1e-12))
        return (1.0 - zncc[good]).mean()

    def score(self, V: torch.Tensor, F: torch.Tensor) -> float:
        with torch.no_grad():
            losses = [self.pair_loss(V, F, i, j) for i, j in self.pairs]
        losses = [float(x) for x in losses if x is not None]
        return float(np.mean(losses)) if losses else float("nan")


def _laplacian(num_vertices: int, faces: np.ndarray) -> torch.Tensor:
    """Uniform (umbrella) Laplacian ``L = I - D^-1 A`` as a sparse ``(V, V)`` tensor."""
    e = edges_of(faces)
    i = np.concatenate([e[:, 0], e[:, 1]])
    j = np.concatenate([e[:, 1], e[:, 0]])
    deg = np.bincount(i, minlength=num_vertices).astype(np.float64)
    w = -1.0 / np.maximum(deg[i], 1)
    idx = np.concatenate([np.stack([i, j]), np.stack([np.arange(num_vertices)] * 2)], axis=1)
    val = np.concatenate([w, (deg > 0).astype(np.float64)])
    return torch.sparse_coo_tensor(
        torch.from_numpy(idx),
        torch.from_numpy(val),
        (num_vertices, num_vertices),
        check_invariants=False,
    ).coalesce()


def refine_vertices(
    vertices: np.ndarray,
    faces: np.ndarray,
    views: Views,
    config: RefineConfig | None = None,
    threads: int | None = None,
) -> RefineResult:
    """Refine mesh vertices ``(V, 3)`` (faces ``(F, 3)``) against the images of ``views``;
    see the module docstring. ``threads`` sets torch's CPU threads for the call (restored after)."""
    config = config or RefineConfig()
    old_threads = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        return _refine(vertices, faces, views, config)
    finally:
        torch.set_num_threads(old_threads)


def _refine(
    vertices: np.ndarray, faces: np.ndarray, views: Views, config: RefineConfig
) -> RefineResult:
    t0 = time.monotonic()
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    views = views.at_most(config.max_views)
    if config.regularizer not in ("displacement", "surface"):
        raise ValueError(
            f"refine.regularizer must be displacement or surface, not {config.regularizer!r}"
        )
    pairs = select_pairs(views, vertices.mean(axis=0), config)
    if not pairs:
        log.warning("refinement: no view pair with a usable baseline; mesh unchanged")
        return RefineResult(vertices, float("nan"), [], float("nan"), 0.0)
    e = edges_of(faces)
    edge_len = float(np.mean(np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1)))
    F_t = torch.from_numpy(faces)
    L = _laplacian(len(vertices), faces)
    # "displacement": the Laplacian of the move from the input; "surface": of the vertices.
    anchor = torch.from_numpy(vertices) if config.regularizer == "displacement" else None
    rng = np.random.default_rng(config.seed)

    full = _Level(views, pairs, 1.0, config)
    full.refresh(vertices, faces)
    best_v, best_score = vertices, full.score(torch.from_numpy(vertices), F_t)
    score_in = best_score
    log.info("refinement: %d pairs, input score %.4f (mean 1 - ZNCC)", len(pairs), score_in)
    current = vertices
    level_scores = []
    for scale in config.scales:
        if time.monotonic() - t0 > config.max_seconds:
            log.info("refinement: time budget spent before level %.2f", scale)
            break
        level = full if scale == 1.0 else _Level(views, pairs, scale, config)
        base = torch.from_numpy(current)
        normals = torch.from_numpy(vertex_normals(current, faces))
        delta = torch.zeros(len(current), dtype=torch.float64, requires_grad=True)
        opt = torch.optim.Adam([delta], lr=config.step * edge_len)
        for it in range(config.iterations):
            if time.monotonic() - t0 > config.max_seconds:
                break
            if it % config.refresh_every == 0:
                level.refresh((base + delta.detach()[:, None] * normals).numpy(), faces)
            V = base + delta[:, None] * normals
            sub = (
                pairs
                if len(pairs) <= config.pairs_per_iteration
                else [
                    pairs[k]
                    for k in rng.choice(len(pairs), config.pairs_per_iteration, replace=False)
                ]
            )
            losses = [x for x in (level.pair_loss(V, F_t, i, j) for i, j in sub) if x is not None]
            if not losses:
                continue
            data = torch.stack(losses).mean()
            lap = torch.sparse.mm(L, V if anchor is None else V - anchor)
            reg = (lap * lap).sum(1).mean() / (edge_len * edge_len)
            loss = data + config.laplacian_weight * reg
            opt.zero_grad()
            loss.backward()
            opt.step()
        current = (base + delta.detach()[:, None] * normals).numpy()
        full.refresh(current, faces)
        s = full.score(torch.from_numpy(current), F_t)
        level_scores.append(s)
        log.info("refinement level %.2f: score %.4f (%.1f s)", scale, s, time.monotonic() - t0)
        if s < best_score:
            best_v, best_score = current, s
    if best_v is vertices:
        log.info("refinement did not improve the photometric score; the input is kept")
    return RefineResult(best_v, score_in, level_scores, best_score, time.monotonic() - t0)
