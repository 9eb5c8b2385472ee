"""MVS figures: PatchMatch speed per depth map, and the oracle check of the stereo.

Speed: one 346x260 reference view with 5 source views of the default scene (GT frames and poses),
the default PatchMatch settings; photometric pass, geometric pass and filter timed separately, for
each thread count (wall and CPU seconds; median of ``--repeat`` runs).

Oracle: GT poses, GT intrinsics and GT sharp frames of the default scene (no SfM) -> run_mvs ->
precision and recall of the fused cloud at 0.5 % of the GT bounding-box diagonal, median depth
error of the maps against GT depth.

The scene's ground truth comes from ``--gt-dir`` (e.g. results/room/gt) or is simulated into a
temporary folder with evdense's simulator (``--scene``, default room).

    PYTHONPATH=src .venv/bin/python benchmarks/bench_mvs.py [--threads 1 2] [--gt-dir DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from evdense.log import setup_logging
from evdense.mvs.oracle import OracleConfig, build_gt_model, evaluate_mvs
from evdense.mvs.patchmatch import PatchMatchConfig, estimate_depth_map, filter_depth_map
from evdense.mvs.stage import MVSConfig, run_mvs
from evdense.mvs.workspace import depth_range, select_source_views, undistort_to_workspace


def _gt_dir(args: argparse.Namespace, tmp: Path) -> Path:
    if args.gt_dir:
        return Path(args.gt_dir)
    from evdense.sim.groundtruth import write_groundtruth

    out = tmp / args.scene / "gt"
    t = time.perf_counter()
    write_groundtruth({"scene": args.scene}, {}, out)
    print(f"simulated ground truth of scene {args.scene!r} in {time.perf_counter() - t:.1f} s")
    return out


def bench_speed(gt: Path, tmp: Path, threads: list[int], repeat: int) -> list[dict]:
    cfg = MVSConfig()
    sparse = build_gt_model(gt, tmp / "speed_model" / "sparse" / "0", OracleConfig(max_frames=40))
    ws = undistort_to_workspace(sparse, gt / "frames", tmp / "speed_ws")
    sources = select_source_views(ws, cfg.view_selection)
    i = max(range(len(ws.images)), key=lambda k: (len(sources[k]), -abs(k - len(ws.images) // 2)))
    ref = ws.stereo_view(ws.images[i].name)
    src = [ws.stereo_view(ws.images[j].name) for j in sources[i]]
    rng = depth_range(ws, i, cfg.view_selection)
    pm = cfg.patch_match
    print(
        f"\nspeed: {ref.image.shape[1]}x{ref.image.shape[0]}, {len(src)} source views, iterations {pm.iterations} "
        f"(coarse to fine) + {pm.geom_iterations} geometric, window {2 * pm.window_radius + 1} px step "
        f"{pm.window_step} {'sparse' if pm.window_sparse else 'dense'}, device cpu"
    )
    # source maps for the geometric pass: photometric maps of the sources (their own sources)
    src_maps = []
    for j in sources[i]:
        sj = [ws.stereo_view(ws.images[q].name) for q in sources[j]]
        m = estimate_depth_map(
            src[sources[i].index(j)], sj, depth_range(ws, j, cfg.view_selection), pm, device="cpu"
        )
        src_maps.append(np.where(m.cost <= cfg.filter.max_cost, m.depth, 0).astype(np.float32))
    rows = []
    for nt in threads:
        torch.set_num_threads(nt)
        estimate_depth_map(ref, src, rng, PatchMatchConfig(iterations=[1]), device="cpu")  # warm-up
        t_ph, c_ph, t_geo, c_geo = [], [], [], []
        for r in range(repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            photo = estimate_depth_map(
                ref, src, rng, PatchMatchConfig(**{**asdict(pm), "seed": r}), device="cpu"
            )
            t1, c1 = time.perf_counter(), time.process_time()
            geo = estimate_depth_map(
                ref, src, rng, pm, init=photo, source_depths=src_maps, device="cpu"
            )
            kept, _ = filter_depth_map(
                ref, src, geo, cfg.filter, source_depths=src_maps, device="cpu"
            )
            t2, c2 = time.perf_counter(), time.process_time()
            t_ph.append(t1 - t0)
            c_ph.append(c1 - c0)
            t_geo.append(t2 - t1)
            c_geo.append(c2 - c1)
        row = {
            "threads": nt,
            "photometric_wall_s": float(np.median(t_ph)),
            "photometric_cpu_s": float(np.median(c_ph)),
            "geometric_and_filter_wall_s": float(np.median(t_geo)),
            "geometric_and_filter_cpu_s": float(np.median(c_geo)),
            "total_wall_s": float(np.median(np.add(t_ph, t_geo))),
            "valid_fraction": kept.valid_fraction,
        }
        rows.append(row)
        print(
            f"  threads {nt}: photometric {row['photometric_wall_s']:.2f} s wall ({row['photometric_cpu_s']:.2f} s cpu), "
            f"geometric + filter {row['geometric_and_filter_wall_s']:.2f} s wall "
            f"({row['geometric_and_filter_cpu_s']:.2f} s cpu), total {row['total_wall_s']:.2f} s per depth map; "
            f"kept {row['valid_fraction']:.1%} of pixels"
        )
    return rows


def bench_oracle(gt: Path, tmp: Path, threads: int, max_frames: int) -> dict:
    print(
        f"\noracle check: GT poses, intrinsics and frames ({max_frames or 'all'} frames), {threads} threads"
    )
    sparse = build_gt_model(
        gt, tmp / "oracle" / "sparse" / "0", OracleConfig(max_frames=max_frames)
    )
    t = time.perf_counter()
    stats = run_mvs(sparse, gt / "frames", tmp / "mvs_oracle", MVSConfig(), threads=threads)
    wall = time.perf_counter() - t
    res = evaluate_mvs(tmp / "mvs_oracle", gt, threshold=0.005)
    print(
        f"  {stats['num_views']} views in {wall:.0f} s (median per map: photometric "
        f"{stats['photometric_time_per_map_s']['median']:.2f} s, geometric + filter "
        f"{stats['geometric_time_per_map_s']['median']:.2f} s; fusion {stats['time_fusion_s']:.1f} s)"
    )
    print(
        f"  precision {res['precision']:.1%}, recall {res['recall']:.1%}, F {res['fscore']:.1%} at "
        f"{res['threshold_m'] * 100:.1f} cm (0.5 % of the {res['bbox_diagonal_m']:.2f} m diagonal); "
        f"{res['fused_points']} fused points, accuracy median {res['accuracy_median_m'] * 100:.2f} cm"
    )
    print(
        f"  depth maps: median relative error {res['depth_median_rel_error']:.3%}, median absolute "
        f"{res['depth_median_abs_error_m'] * 1000:.1f} mm, kept {res['depth_kept_fraction']:.1%} of the pixels with GT depth"
    )
    return {
        "run": {k: v for k, v in stats.items() if k not in ("config", "maps")},
        "evaluation": res,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--gt-dir", help="ground-truth folder (results/{dataset}/gt); default: simulate --scene"
    )
    ap.add_argument(
        "--scene", default="room", help="scene preset simulated when --gt-dir is not given"
    )
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--oracle-frames", type=int, default=OracleConfig().max_frames)
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-oracle", action="store_true")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    setup_logging(level=30)
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="bench_mvs_") as d:
        tmp = Path(d)
        gt = _gt_dir(args, tmp)
        if not args.skip_speed:
            out["speed"] = bench_speed(gt, tmp, args.threads, args.repeat)
        if not args.skip_oracle:
            out["oracle"] = bench_oracle(gt, tmp, max(args.threads), args.oracle_frames)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
