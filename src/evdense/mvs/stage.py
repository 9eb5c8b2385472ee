"""The multi-view stereo stage: sparse model + frames -> dense workspace, depth maps, fused cloud.

:func:`run_mvs` writes into one folder (COLMAP's dense-workspace layout, see
:mod:`evdense.mvs.workspace`): ``images/``, ``sparse/``, ``stereo/`` (maps, previews, per-map
stats), ``fused.ply`` (+ ``fused.ply.vis``) and ``stats.json``. Steps:

1. undistortion of the registered frames (``pycolmap.undistort_images``);
2. source views and depth range per image from the sparse points;
3. photometric PatchMatch, one reference view at a time (``*.photometric.bin``, raw);
4. geometric pass: PatchMatch iterations whose cost adds the forward-backward reprojection error
   against the source views' photometric maps, then filtering (cost, agreeing views,
   triangulation angle) -> ``*.geometric.bin``, the maps that fusion reads;
5. fusion and outlier removal -> ``fused.ply``.

Every map is written atomically and skipped when present, so an interrupted run resumes where it
stopped; memory holds one reference view and its sources at a time.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import time
from collections import OrderedDict
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from evdense.config import section_from_dict
from evdense.formats.cloud import write_cloud
from evdense.formats.files import write_json_atomic
from evdense.log import get_logger, progress
from evdense.mvs.fusion import FusionConfig, fuse_workspace
from evdense.mvs.maps_io import write_colmap_array, write_previews
from evdense.mvs.patchmatch import (
    MAX_COST,
    DepthNormalMap,
    FilterConfig,
    PatchMatchConfig,
    StereoView,
    estimate_depth_map,
    filter_depth_map,
    resolve_device,
)
from evdense.mvs.workspace import (
    ViewSelectionConfig,
    Workspace,
    depth_range,
    discard_stale_workspace,
    input_fingerprint,
    read_workspace,
    select_source_views,
    undistort_to_workspace,
    write_patch_match_cfg,
)

log = get_logger("mvs")

MAP_KINDS = ("photometric", "geometric")  # the two passes, in order


@dataclass
class MVSConfig:
    """Settings of the multi-view stereo stage (the ``mvs`` config section)."""

    view_selection: ViewSelectionConfig = field(default_factory=ViewSelectionConfig)
    """Source views and depth range of each reference view, from the sparse points."""
    patch_match: PatchMatchConfig = field(default_factory=PatchMatchConfig)
    """PatchMatch depth and normal estimation (Bleyer et al. 2011; Schoenberger et al. 2016)."""
    filter: FilterConfig = field(default_factory=FilterConfig)
    """Which depth-map pixels are kept (the others get depth 0)."""
    fusion: FusionConfig = field(default_factory=FusionConfig)
    """Fusion of the kept depth-map pixels into one point cloud, then statistical outlier
    removal."""
    geometric: bool = True
    """Run the geometric-consistency PatchMatch iterations (cost + forward-backward reprojection
    error against the source views' maps); false = only filter the photometric maps."""
    max_image_size: int = -1
    """Undistorted images larger than this (pixels, longer side) are downsized; -1 = keep."""
    device: str = "auto"
    """Torch device of PatchMatch: auto (CUDA when available), cpu, cuda."""
    previews: bool = True
    """Write PNG previews of the final depth and normal maps (stereo/previews)."""
    view_cache: int = 32
    """Views (images) held in memory between reference views."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> MVSConfig:
        """Build from the ``mvs`` config section; unknown keys raise ``ValueError`` naming them."""
        cfg = section_from_dict(cls, d, "mvs")
        cfg.view_selection.depth_percentiles = tuple(cfg.view_selection.depth_percentiles)
        return cfg

    def check(self) -> None:
        self.patch_match.check()
        self.fusion.check()
        if self.device not in ("auto", "cpu", "cuda") and not self.device.startswith("cuda:"):
            raise ValueError(f"mvs.device must be auto, cpu or cuda, got {self.device!r}")
        if self.view_selection.num_source_views < 1:
            raise ValueError("mvs.view_selection.num_source_views must be >= 1")


class _ViewCache:
    def __init__(self, ws: Workspace, size: int):
        self.ws, self.size, self.views = ws, max(1, size), OrderedDict()

    def get(self, i: int) -> StereoView:
        if i in self.views:
            self.views.move_to_end(i)
            return self.views[i]
        v = self.ws.stereo_view(self.ws.images[i].name)
        self.views[i] = v
        while len(self.views) > self.size:
            self.views.popitem(last=False)
        return v


def _write_maps(ws: Workspace, name: str, kind: str, m: DepthNormalMap) -> None:
    for what in ("depth", "normal", "cost"):
        p = ws.map_path(what, name, kind)
        p.parent.mkdir(parents=True, exist_ok=True)
    # cost last: has_maps() checks all three, so a map counts only once complete
    write_colmap_array(ws.map_path("depth", name, kind), m.depth)
    write_colmap_array(ws.map_path("normal", name, kind), m.normal)
    write_colmap_array(ws.map_path("cost", name, kind), m.cost)


def _map_stats_path(ws: Workspace, name: str, kind: str) -> Path:
    return ws.root / "stereo" / "stats" / f"{name}.{kind}.json"


class _Job:
    """What one process needs to compute maps of any view of a workspace (picklable)."""

    def __init__(
        self,
        root: Path,
        cfg: MVSConfig,
        sources: list[list[int]],
        ranges: list[tuple[float, float] | None],
        device: str,
    ):
        self.root, self.cfg, self.sources, self.ranges, self.device = (
            root,
            cfg,
            sources,
            ranges,
            device,
        )
        self._ws: Workspace | None = None
        self._cache: _ViewCache | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_ws": None, "_cache": None}

    @property
    def ws(self) -> Workspace:
        if self._ws is None:
            self._ws = read_workspace(self.root)
        return self._ws

    def view(self, i: int) -> StereoView:
        if self._cache is None:
            self._cache = _ViewCache(self.ws, self.cfg.view_cache)
        return self._cache.get(i)

    def photometric(self, i: int) -> None:
        """Compute and write the raw photometric maps of view ``i`` (and their stats)."""
        ws, cfg = self.ws, self.cfg
        t0 = time.perf_counter()
        im = ws.images[i]
        src, rng = self.sources[i], self.ranges[i]
        if not src or rng is None:
            log.warning(
                "%s: no source view or no depth range (no sparse points); empty depth map", im.name
            )
            m = DepthNormalMap.empty(im.height, im.width)
        else:
            pm = PatchMatchConfig(**{**asdict(cfg.patch_match), "seed": cfg.patch_match.seed + i})
            m = estimate_depth_map(
                self.view(i), [self.view(j) for j in src], rng, pm, device=self.device, name=im.name
            )
        _write_maps(ws, im.name, "photometric", m)
        write_json_atomic(
            _map_stats_path(ws, im.name, "photometric"),
            {
                "time_s": time.perf_counter() - t0,
                "sources": [ws.images[j].name for j in src],
                "depth_range": rng,
                "matched_fraction": float((m.cost < cfg.filter.max_cost).mean()),
            },
            indent=1,
        )

    def geometric(self, i: int) -> None:
        """Geometric-consistency iterations and filtering of view ``i``: the final maps."""
        ws, cfg = self.ws, self.cfg
        t0 = time.perf_counter()
        im = ws.images[i]
        raw = ws.read_maps(im.name, "photometric")
        src, rng = self.sources[i], self.ranges[i]
        counts = None
        if not src or rng is None or not (raw.depth > 0).any():
            out = DepthNormalMap.empty(im.height, im.width)
        else:
            src_depths = []
            for j in src:
                sm = ws.read_maps(ws.images[j].name, "photometric")
                src_depths.append(
                    np.where(sm.cost <= cfg.filter.max_cost, sm.depth, 0).astype(np.float32)
                )
            ref, src_views = self.view(i), [self.view(j) for j in src]
            m = raw
            if cfg.geometric and cfg.patch_match.geom_iterations > 0:
                pm = PatchMatchConfig(
                    **{**asdict(cfg.patch_match), "seed": cfg.patch_match.seed + 7919 + i}
                )
                m = estimate_depth_map(
                    ref,
                    src_views,
                    rng,
                    pm,
                    init=raw,
                    source_depths=src_depths,
                    device=self.device,
                    name=im.name,
                )
            use = src_depths if cfg.filter.min_consistent_views > 0 else None
            out, counts = filter_depth_map(
                ref, src_views, m, cfg.filter, source_depths=use, device=self.device
            )
        _write_maps(ws, im.name, "geometric", out)
        if cfg.previews:
            write_previews(ws.preview_stem(im.name, "geometric"), out.depth, out.normal)
        kept = out.depth > 0
        checked = counts[counts >= 0] if counts is not None else np.zeros(0)
        write_json_atomic(
            _map_stats_path(ws, im.name, "geometric"),
            {
                "time_s": time.perf_counter() - t0,
                "valid_fraction": out.valid_fraction,
                "median_cost": float(np.median(out.cost[kept])) if kept.any() else MAX_COST,
                "mean_agreeing_views": float(checked.mean()) if len(checked) else 0.0,
            },
            indent=1,
        )


class _WarningCollector(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


_WORKER_JOB: _Job | None = None


def _worker_init(job: _Job) -> None:
    global _WORKER_JOB
    torch.set_num_threads(1)
    _WORKER_JOB = job


def _worker_run(kind: str, i: int) -> list[str]:
    """Run one map in a worker process; returns the warnings it logged (the parent re-logs them)."""
    assert _WORKER_JOB is not None
    handler = _WarningCollector()
    logger = get_logger()
    logger.addHandler(handler)
    try:
        getattr(_WORKER_JOB, kind)(i)
    finally:
        logger.removeHandler(handler)
    return handler.messages


def _compute_depth_maps(ws: Workspace, cfg: MVSConfig, workers: int = 1) -> None:
    """Steps 2-4 of the stage on an undistorted workspace (resumable; see the module docstring).

    ``workers`` > 1 (CPU only): that many processes, one torch thread each, work on different
    reference views (PatchMatch's small tensor operations scale better this way than with
    intra-op threads).
    """
    n = len(ws.images)
    sources = select_source_views(ws, cfg.view_selection)
    write_patch_match_cfg(ws, sources)
    ranges = [depth_range(ws, i, cfg.view_selection) for i in range(n)]
    dev = resolve_device(cfg.device)
    workers = max(1, int(workers)) if dev.type == "cpu" else 1
    job = _Job(ws.root, cfg, sources, ranges, str(dev))
    job._ws = ws
    todo = {k: [i for i in range(n) if not ws.has_maps(ws.images[i].name, k)] for k in MAP_KINDS}
    for kind in MAP_KINDS:
        if len(todo[kind]) < n:
            log.info("%s maps: %d of %d present, reused", kind, n - len(todo[kind]), n)
    n_proc = min(workers, max(len(t) for t in todo.values()))
    if n_proc <= 1:
        log.info("%s: PatchMatch on %s, %d threads", ws.root, dev, torch.get_num_threads())
        for kind in MAP_KINDS:
            for i in progress(todo[kind], desc=f"{kind} depth maps", logger=log):
                getattr(job, kind)(i)
        return
    # one pool for both passes (a worker's start-up costs seconds); the geometric pass starts
    # once every photometric map exists, as it reads the source views' maps
    log.info("%s: PatchMatch on %s, %d processes x 1 thread", ws.root, dev, n_proc)
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        n_proc, mp_context=ctx, initializer=_worker_init, initargs=(job,)
    ) as pool:
        for kind in MAP_KINDS:
            futures = [pool.submit(_worker_run, kind, i) for i in todo[kind]]
            for fut in progress(
                as_completed(futures), total=len(futures), desc=f"{kind} depth maps", logger=log
            ):
                for msg in fut.result():
                    log.warning("%s", msg)


def run_mvs(
    sparse_dir: str | Path,
    image_dir: str | Path,
    out_dir: str | Path,
    config: MVSConfig | dict[str, Any] | None = None,
    threads: int | None = None,
) -> dict[str, Any]:
    """Dense reconstruction of the COLMAP model ``sparse_dir`` (images in ``image_dir``) into
    ``out_dir``: the dense workspace, ``fused.ply`` (+ ``.vis``) and ``stats.json`` (returned).

    ``threads``: on the CPU, that many worker processes (one torch thread each) compute maps of
    different views; PatchMatch runs single-threaded on the CPU in any case, since torch's
    intra-op threads were measured to slow its small tensor operations down (badly so on a
    shared machine). None = 1 process. Resumable: existing undistortion and maps are reused.
    Raises ``ValueError`` naming the folder when the model or frames are missing.
    """
    cfg = config if isinstance(config, MVSConfig) else MVSConfig.from_dict(config)
    torch_threads = torch.get_num_threads()
    if resolve_device(cfg.device).type == "cpu":
        torch.set_num_threads(1)
    try:
        return _run_mvs(sparse_dir, image_dir, out_dir, cfg, threads)
    finally:
        torch.set_num_threads(torch_threads)


def _run_mvs(
    sparse_dir: str | Path,
    image_dir: str | Path,
    out_dir: str | Path,
    cfg: MVSConfig,
    threads: int | None,
) -> dict[str, Any]:
    """:func:`run_mvs` once its config is resolved and torch's threads are set."""
    out_dir = Path(out_dir)
    t0 = time.perf_counter()
    discard_stale_workspace(out_dir, input_fingerprint(Path(sparse_dir), Path(image_dir), cfg))
    ws = undistort_to_workspace(sparse_dir, image_dir, out_dir, cfg.max_image_size)
    t_undistort = time.perf_counter() - t0
    _compute_depth_maps(ws, cfg, workers=threads or 1)
    t1 = time.perf_counter()
    cloud = fuse_workspace(ws, cfg.fusion, "geometric", num_threads=threads or -1)
    write_cloud(out_dir / "fused.ply", cloud)
    t_fuse = time.perf_counter() - t1

    per_map = []
    for im in ws.images:
        rec: dict[str, Any] = {"name": im.name}
        for kind in ("photometric", "geometric"):
            p = _map_stats_path(ws, im.name, kind)
            if p.is_file():
                rec[kind] = json.loads(p.read_text())
        per_map.append(rec)
    times = [r["photometric"]["time_s"] for r in per_map if "photometric" in r]
    gtimes = [r["geometric"]["time_s"] for r in per_map if "geometric" in r]
    valid = [r["geometric"]["valid_fraction"] for r in per_map if "geometric" in r]
    stats = {
        "num_views": len(ws.images),
        "image_size": [ws.images[0].width, ws.images[0].height],
        "device": str(resolve_device(cfg.device)),
        "threads": threads,
        "fused_points": len(cloud),
        "time_undistort_s": t_undistort,
        "time_fusion_s": t_fuse,
        "time_total_s": time.perf_counter() - t0,
        "photometric_time_per_map_s": {
            "median": float(np.median(times)) if times else None,
            "total": float(np.sum(times)),
        },
        "geometric_time_per_map_s": {
            "median": float(np.median(gtimes)) if gtimes else None,
            "total": float(np.sum(gtimes)),
        },
        "valid_fraction": {
            "median": float(np.median(valid)) if valid else 0.0,
            "mean": float(np.mean(valid)) if valid else 0.0,
        },
        "config": _jsonable(asdict(cfg)),
        "maps": per_map,
    }
    write_json_atomic(out_dir / "stats.json", stats, indent=1)
    log.info(
        "%s: %d views, %d fused points, %.1f s (median %.2f s per photometric map)",
        out_dir,
        len(ws.images),
        len(cloud),
        stats["time_total_s"],
        stats["photometric_time_per_map_s"]["median"] or 0.0,
    )
    return stats


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x
