"""Mesh clean-up variants against ground truth on a finished run: which steps help, which hurt?

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_cleanup.py [--results results]
           [--dataset room_fast] [--sources gt ours_n25000_b5] [--iterations 1 5]

For each source the visibility mesher is run again on the workflow's dense cloud
(``mvs/<source>/fused.ply``, default ``mesh.visibility`` settings) to get the raw mesh the
clean-up starts from; then the clean-up is run with the default ``mesh.cleanup`` settings and with
variants: Taubin smoothing for each of ``--iterations`` in each border mode (free, curve, pinned),
no hole closing, no small-component removal. Every mesh is moved into the GT frame with the
alignment the source's evaluation found and scored like the evaluation scores meshes (F at the
evaluation's thresholds, 0.25, 0.5, 1 and 2 % of the GT diagonal, completeness on the observed GT surface); the dense cloud's F
from ``eval/<source>/metrics.json`` is printed beside them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import open3d as o3d
from bench_refine import scored

from evdense.evaluate.config import EvalConfig
from evdense.evaluate.geometry_metrics import gt_reference_samples
from evdense.formats.cloud import read_cloud
from evdense.mesh.cleanup import BOUNDARY_MODES, CleanupConfig, clean_mesh
from evdense.mesh.views import read_views
from evdense.mesh.visibility import VisibilityConfig, visibility_mesh

ROOT = Path(__file__).resolve().parents[1]


def fmt(fscores: list[float]) -> str:
    return " / ".join(f"{x:.4f}" for x in fscores)


def variants(iterations: list[int]) -> list[tuple[str, CleanupConfig]]:
    base = CleanupConfig()
    out = [(f"default ({base.smooth_iterations} smoothing iterations)", base)]
    for k in iterations:
        for mode in BOUNDARY_MODES:
            out.append(
                (
                    f"{k} iterations, {mode}",
                    dataclasses.replace(base, smooth_iterations=k, smooth_boundary=mode),
                )
            )
    out.append(("no hole closing", dataclasses.replace(base, max_hole_edges=0)))
    out.append(("no component removal", dataclasses.replace(base, min_component_fraction=0.0)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default=str(ROOT / "results"))
    ap.add_argument("--dataset", default="room_fast")
    ap.add_argument("--sources", nargs="+", default=["gt", "ours_n25000_b5"])
    ap.add_argument("--iterations", nargs="+", type=int, default=[1, 5])
    args = ap.parse_args()
    ds = Path(args.results) / args.dataset
    gt = o3d.io.read_triangle_mesh(str(ds / "gt" / "mesh.ply"))
    eval_conf = EvalConfig()
    gt_samples, _ = gt_reference_samples(ds / "gt", gt, eval_conf)
    for src in args.sources:
        metrics = json.loads((ds / "eval" / src / "metrics.json").read_text())
        pc = read_cloud(ds / "mvs" / src / "fused.ply")
        views = read_views(ds / "mvs" / src)
        t0 = time.monotonic()
        raw = visibility_mesh(
            pc.points, pc.visibility, views.centers, VisibilityConfig(), pc.colors_float()
        )
        print(f"\n{args.dataset} / {src}: raw mesh {len(raw.triangles)} faces "
              f"({time.monotonic() - t0:.0f} s); F at 0.25 / 0.5 / 1 / 2 %")  # fmt: skip
        print("| clean-up | F | faces |\n|---|---|---|")
        dense = metrics["geometry"]["dense"]["fscore"]
        print(f"| dense cloud (from its evaluation) | {fmt(dense)} | |")
        rows = [("raw mesher output", raw)]
        rows += [(name, clean_mesh(raw, conf)) for name, conf in variants(args.iterations)]
        for name, mesh in rows:
            v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
            fs = scored(v, f, metrics, gt, gt_samples, eval_conf.relative_thresholds)
            print(f"| {name} | {fmt(fs)} | {len(f)} |", flush=True)


if __name__ == "__main__":
    main()
