"""Refinement against ground truth on a finished run: does it make the mesh better or worse?

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_refine.py [--results results]
           [--dataset room_fast] [--sources gt conventional ours_n25000_b5]
           [--set key=value ...] [--max-seconds 60] [--threads 2]

For each source, the workflow's raw mesh (``mesh/<source>/visibility/mesh.ply``) is refined with
the default ``mesh.refine`` settings overridden by ``--set`` (e.g. ``--set regularizer=surface``),
moved into the GT frame with the alignment its evaluation found (``eval/<source>/metrics.json``:
Sim(3) then ICP), and scored like the evaluation scores meshes (precision / recall / F at 0.5, 1
and 2 % of the GT diagonal, completeness on the observed GT surface). Printed per source: F of the
input and of the refined mesh, the change, the photometric score (mean 1 - ZNCC) before and after,
the median and largest vertex move (in mean edge lengths), and the time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import open3d as o3d
import yaml

from evdense.evaluate.align import apply_h, apply_sim3
from evdense.evaluate.config import EvalConfig
from evdense.evaluate.geometry_metrics import evaluate_geometry, gt_reference_samples
from evdense.mesh.geometry import edges_of
from evdense.mesh.views import make_mesh, read_mesh, read_views
from evdense.refine.photometric import RefineConfig, refine_vertices

ROOT = Path(__file__).resolve().parents[1]
THRESHOLDS = [0.005, 0.01, 0.02]


def scored(vertices: np.ndarray, faces: np.ndarray, metrics: dict, gt: o3d.geometry.TriangleMesh,
           gt_samples: np.ndarray | None, thresholds=THRESHOLDS) -> list[float]:  # fmt: skip
    """F-scores of a mesh in the run's frame, moved into the GT frame with the alignment its
    evaluation found (``metrics``: Sim(3) then ICP), at ``thresholds`` (fractions of the diagonal)."""
    a = metrics["alignment"]
    v = apply_sim3(a["scale"], np.array(a["R"]), np.array(a["t"]), vertices)
    mesh = make_mesh(apply_h(np.array(a["icp"]), v), faces)
    conf = EvalConfig()
    g = evaluate_geometry(
        mesh, gt, thresholds, conf.num_samples, conf.crop_margin, gt_samples=gt_samples
    ).to_dict()
    return list(g["fscore"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default=str(ROOT / "results"))
    ap.add_argument("--dataset", default="room_fast")
    ap.add_argument("--sources", nargs="+", default=["gt", "conventional", "ours_n25000_b5"])
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    ap.add_argument("--max-seconds", type=float, default=60.0)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    overrides = dict(kv.split("=", 1) for kv in args.set)
    conf = RefineConfig(max_seconds=args.max_seconds)
    conf = dataclasses.replace(conf, **{k: yaml.safe_load(v) for k, v in overrides.items()})
    ds = Path(args.results) / args.dataset
    gt = o3d.io.read_triangle_mesh(str(ds / "gt" / "mesh.ply"))
    gt_samples, _ = gt_reference_samples(ds / "gt", gt, EvalConfig())
    print(
        f"refinement {overrides or 'defaults'}, budget {conf.max_seconds:g} s, {args.threads} threads"
    )
    print(
        "| source | F@0.5/1/2 % input | refined | change at 1 % | 1 - ZNCC in -> out | move median / max (edges) | s |"
    )
    print("|---|---|---|---|---|---|---|")
    for src in args.sources:
        mesh_dir = ds / "mesh" / src / "visibility"
        metrics = json.loads((ds / "eval" / src / "metrics.json").read_text())
        m = read_mesh(mesh_dir / "mesh.ply")
        v, f = np.asarray(m.vertices), np.asarray(m.triangles)
        views = read_views(ds / "mvs" / src)
        t0 = time.monotonic()
        res = refine_vertices(v, f, views, conf, threads=args.threads)
        seconds = time.monotonic() - t0
        e = edges_of(f)
        edge = float(np.mean(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)))
        move = np.linalg.norm(res.vertices - v, axis=1) / edge
        f_in, f_out = (
            scored(v, f, metrics, gt, gt_samples),
            scored(res.vertices, f, metrics, gt, gt_samples),
        )
        print(
            f"| {src} | {'/'.join(f'{x:.3f}' for x in f_in)} | {'/'.join(f'{x:.3f}' for x in f_out)} | "
            f"{f_out[1] - f_in[1]:+.4f} | {res.score_input:.4f} -> {res.score_output:.4f} | "
            f"{np.median(move):.3f} / {move.max():.2f} | {seconds:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
