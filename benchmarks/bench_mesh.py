"""Mesh, refinement and texture figures: geometry against the GT mesh, photometric quality of the
textured mesh from held-out cameras, and the time of each step.

Synthetic case (default; needs nothing else): a scene of a ground square, a box and a sphere,
procedurally coloured, seen by 24 DAVIS346 cameras (two rings) with 6 held-out cameras between
them. The "dense cloud" stands in for MVS: points sampled on the GT surfaces seen by at least two
cameras, with Gaussian noise along the normal (``--noise``, fraction of the GT bounding-box
diagonal), noisy normals (10 degrees) and uniform outliers (``--outliers``). Then:

- mesh_surface (poisson and visibility, estimated visibility, default clean-up): F-score against
  the GT mesh at 0.25/0.5/1/2 % of the diagonal, beside the cloud's own;
- refine_mesh of the visibility mesh: accuracy and F-score before and after, photometric score;
- texture_mesh of the refined mesh: PSNR of renders from the held-out cameras against GT images
  (pixels where both see the surface; also the exact GT mesh textured, as the texture's own bound);
- wall time of every step.

Real pipeline (``--workspace results/{d}/mvs/{source} --gt-dir results/{d}/gt``): the same steps
on a dense workspace whose world frame is the GT frame (source ``oracle``; other sources need a
Sim(3) alignment first, which the evaluation stage does), holding out every ``--holdout-every``-th view
from texturing and rendering it against that view's image.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_mesh.py [--points 150000] [--noise 0.002]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import open3d as o3d

from evdense.camera import davis346
from evdense.evaluate.geometry_metrics import evaluate_geometry
from evdense.evaluate.rendering import render_textured
from evdense.formats.cloud import read_cloud
from evdense.log import setup_logging
from evdense.mesh.cleanup import BOUNDARY_MODES, clean_mesh
from evdense.mesh.geometry import make_scene, project, raycast_view
from evdense.mesh.poisson import poisson_mesh
from evdense.mesh.stage import MeshConfig
from evdense.mesh.views import Views, make_mesh, read_mesh, read_views
from evdense.mesh.visibility import estimate_visibility, visibility_mesh
from evdense.refine.photometric import RefineConfig, refine_vertices
from evdense.testing.mesh_scenes import (
    box_mesh,
    grid_plane,
    make_views,
    orbit_poses,
    smooth_colour,
    sphere_mesh,
)
from evdense.texture import TextureConfig, texture_mesh_views

RELATIVE = (0.0025, 0.005, 0.01, 0.02)


def scene_mesh() -> tuple[np.ndarray, np.ndarray]:
    """Ground square 3 m wide, a 0.8 m box and a 0.45 m sphere standing on it."""
    parts = [
        grid_plane(3.0, 40),
        box_mesh(0.8, 10, center=(-0.5, 0.25, 0.4)),
        sphere_mesh(0.45, 40),
    ]
    parts[2] = (parts[2][0] + np.array([0.6, -0.35, 0.45]), parts[2][1])
    verts, faces, n = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def colour(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    return smooth_colour(p, n, freq=9.0)


def visible_samples(
    v, f, views: Views, n: int, min_views: int, rng
) -> tuple[np.ndarray, np.ndarray]:
    """Points on the mesh seen (depth test) by at least ``min_views`` views, with their normals."""
    from evdense.testing.mesh_scenes import sample_cloud

    pts, nrm = sample_cloud(v, f, 3 * n, seed=int(rng.integers(1 << 30)))
    scene = make_scene(v, f)
    count = np.zeros(len(pts), int)
    for cam, T in zip(views.cameras, views.poses, strict=True):
        depth = raycast_view(scene, cam, T).depth
        uv, z = project(pts, cam, T)
        ui, vi = np.rint(uv[:, 0]), np.rint(uv[:, 1])
        ok = (z > 0) & (ui >= 0) & (vi >= 0) & (ui < cam.width) & (vi < cam.height)
        ok[ok] &= np.abs(z[ok] - depth[vi[ok].astype(int), ui[ok].astype(int)]) < 0.005 * z[ok]
        count += ok
    keep = np.nonzero(count >= min_views)[0]
    keep = rng.choice(keep, size=min(n, len(keep)), replace=False)
    return pts[keep], nrm[keep]


def perturb(pts, nrm, diag, noise, outliers, rng):
    pts = pts + nrm * rng.normal(scale=noise * diag, size=(len(pts), 1))
    nrm = nrm + rng.normal(scale=np.tan(np.deg2rad(10.0)) / np.sqrt(2), size=nrm.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    k = int(outliers * len(pts))
    lo, hi = pts.min(0), pts.max(0)
    out = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), size=(k, 3))
    on = rng.normal(size=(k, 3))
    on /= np.linalg.norm(on, axis=1, keepdims=True)
    return np.concatenate([pts, out]), np.concatenate([nrm, on])


def geometry_row(name: str, recon, gt, seconds: float | None) -> dict:
    m = evaluate_geometry(recon, gt, RELATIVE, num_samples=200_000)
    return {
        "name": name,
        "accuracy_mean_m": m.accuracy_mean,
        "completeness_mean_m": m.completeness_mean,
        "precision": m.precision,
        "recall": m.recall,
        "fscore": m.fscore,
        "seconds": seconds,
        "faces": len(recon.triangles) if isinstance(recon, o3d.geometry.TriangleMesh) else None,
    }


def psnr_held_out(
    tm, views: Views, gts: list[np.ndarray], gt_masks: list[np.ndarray] | None = None
) -> dict:
    """PSNR (dB) of textured renders against GT images over pixels where both see the surface
    (or where the GT mask is set), averaged over held-out views; plus the coverage."""
    psnrs, cover = [], []
    for i, gt in enumerate(gts):
        img, mask = render_textured(tm, views.cameras[i], views.poses[i])
        gm = gt_masks[i] if gt_masks is not None else np.ones(mask.shape, bool)
        both = mask & gm
        if gt.ndim == 2:
            gt = gt[..., None]
        g = gt.mean(axis=2) if img.shape[2] == 1 else gt
        r = img.mean(axis=2) if g.ndim == 2 else img
        mse = float(np.mean((r[both] - g[both]) ** 2)) if both.any() else float("nan")
        psnrs.append(10 * np.log10(1.0 / mse))
        cover.append(float(both.sum() / max(gm.sum(), 1)))
    return {
        "psnr_db": float(np.mean(psnrs)),
        "psnr_min_db": float(np.min(psnrs)),
        "coverage": float(np.mean(cover)),
    }


@dataclasses.dataclass
class StageConfigs:
    """The default configs of the mesh, refine and texture stages with this script's overrides."""

    mesh: MeshConfig
    refine: RefineConfig
    texture: TextureConfig


def mesh_config(args) -> StageConfigs:
    """The default stage configs with this script's overrides."""
    conf = StageConfigs(
        MeshConfig(), RefineConfig(max_seconds=args.refine_seconds), TextureConfig()
    )
    if args.smooth_iterations is not None:
        conf.mesh.cleanup.smooth_iterations = args.smooth_iterations
    if args.smooth_boundary is not None:
        conf.mesh.cleanup.smooth_boundary = args.smooth_boundary
    return conf


def run_synthetic(args) -> dict:
    rng = np.random.default_rng(0)
    conf = mesh_config(args)
    v, f = scene_mesh()
    gt = make_mesh(v, f)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    cam = davis346()
    target = (0.0, 0.0, 0.3)
    train_poses = np.concatenate(
        [orbit_poses(12, 3.2, target, 20.0), orbit_poses(12, 3.0, target, 45.0, phase=0.26)]
    )
    test_poses = orbit_poses(6, 3.1, target, 32.0, phase=0.5)
    t = time.monotonic()
    train = make_views(v, f, cam, train_poses, colour)
    test = make_views(v, f, cam, test_poses, colour)
    test_masks = [np.isfinite(raycast_view(make_scene(v, f), cam, T).depth) for T in test_poses]
    print(
        f"rendered {len(train)} training and {len(test)} held-out views in {time.monotonic() - t:.1f} s"
    )
    pts, nrm = visible_samples(v, f, train, args.points, 2, rng)
    pts, nrm = perturb(pts, nrm, diag, args.noise, args.outliers, rng)
    print(
        f"cloud: {len(pts)} points (noise {args.noise * diag * 1000:.1f} mm, {args.outliers:.0%} outliers)"
    )
    return evaluate_all(
        pts, nrm, None, train, test, list(test.images), test_masks, gt, conf, args, v, f
    )


def evaluate_all(
    pts, nrm, colors, train, test, test_images, test_masks, gt, conf, args, v_gt=None, f_gt=None
):
    rows = [geometry_row("dense cloud", pts, gt, None)]
    t = time.monotonic()
    mesh_p = clean_mesh(
        poisson_mesh(pts, nrm, conf.mesh.poisson, colors, train.centers), conf.mesh.cleanup
    )
    rows.append(geometry_row("poisson + clean-up", mesh_p, gt, time.monotonic() - t))
    t = time.monotonic()
    vis = estimate_visibility(pts, nrm, train, conf.mesh.visibility)
    t_vis = time.monotonic() - t
    mesh_v = clean_mesh(
        visibility_mesh(pts, vis, train.centers, conf.mesh.visibility, colors), conf.mesh.cleanup
    )
    rows.append(geometry_row("visibility + clean-up", mesh_v, gt, time.monotonic() - t))
    rows[-1]["visibility_estimate_s"] = t_vis
    vv, fv = np.asarray(mesh_v.vertices), np.asarray(mesh_v.triangles)
    res = refine_vertices(vv, fv, train, conf.refine, threads=args.threads)
    refined = make_mesh(res.vertices, fv)
    rows.append(geometry_row("visibility refined", refined, gt, res.seconds))
    rows[-1]["photometric_score"] = [res.score_input, res.score_output]
    t = time.monotonic()
    tm = texture_mesh_views(res.vertices, fv, train, conf.texture)
    t_tex = time.monotonic() - t
    texture = {
        "seconds": t_tex,
        "atlas": list(tm.atlas.shape[:2]),
        **psnr_held_out(tm, test, test_images, test_masks),
    }
    if v_gt is not None:
        tm_gt = texture_mesh_views(v_gt, f_gt, train, conf.texture)
        texture["gt_mesh"] = psnr_held_out(tm_gt, test, test_images, test_masks)
    plain = dataclasses.replace(conf.texture, level_seams=False)
    tm_nolevel = texture_mesh_views(res.vertices, fv, train, plain)
    texture["without_seam_levelling"] = psnr_held_out(tm_nolevel, test, test_images, test_masks)
    return {"geometry": rows, "texture": texture}


def run_workspace(args) -> dict:
    """The same steps on a real dense workspace whose world frame is the GT frame."""
    ws = Path(args.workspace)
    conf = mesh_config(args)
    views = read_views(ws)
    k = args.holdout_every
    test_idx = list(range(k // 2, len(views), k))
    train = views.subset([i for i in range(len(views)) if i not in test_idx])
    test = views.subset(test_idx)
    pc = read_cloud(ws / "fused.ply")
    gt = read_mesh(Path(args.gt_dir) / "mesh.ply")
    test_images = [test.image(i) for i in range(len(test))]
    # A .vis file indexes all views; the benchmark re-estimates visibility from the training views.
    return evaluate_all(
        pc.points, pc.normals, pc.colors_float(), train, test, test_images, None, gt, conf, args
    )


def print_report(out: dict) -> None:
    print("\nGeometry against the GT mesh (F-score at 0.25 / 0.5 / 1 / 2 % of the GT diagonal)")
    print(
        f"{'':24s} {'acc mean mm':>11s} {'comp mean mm':>12s} {'F-scores':>28s} {'faces':>8s} {'time s':>7s}"
    )
    for r in out["geometry"]:
        fs = " ".join(f"{x:.3f}" for x in r["fscore"])
        faces = "" if r["faces"] is None else str(r["faces"])
        secs = "" if r["seconds"] is None else f"{r['seconds']:.1f}"
        print(
            f"{r['name']:24s} {1000 * r['accuracy_mean_m']:11.2f} {1000 * r['completeness_mean_m']:12.2f} "
            f"{fs:>28s} {faces:>8s} {secs:>7s}"
        )
    print("precision / recall at the same thresholds")
    for r in out["geometry"]:
        pr = "  ".join(f"{p:.3f}/{q:.3f}" for p, q in zip(r["precision"], r["recall"], strict=True))
        print(f"{r['name']:24s} {pr}")
    ref = [r for r in out["geometry"] if "photometric_score" in r]
    if ref:
        a, b = ref[0]["photometric_score"]
        print(f"refinement photometric score (mean 1 - ZNCC): {a:.4f} -> {b:.4f}")
    t = out["texture"]
    print(
        f"\nTexture: {t['seconds']:.1f} s, atlas {t['atlas'][1]}x{t['atlas'][0]}; held-out PSNR "
        f"{t['psnr_db']:.2f} dB (min {t['psnr_min_db']:.2f}), coverage {t['coverage']:.1%}"
    )
    if "gt_mesh" in t:
        print(f"  exact GT mesh textured the same way: {t['gt_mesh']['psnr_db']:.2f} dB")
    print(f"  without seam levelling: {t['without_seam_levelling']['psnr_db']:.2f} dB")


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--points", type=int, default=150_000, help="cloud size (synthetic)")
    ap.add_argument(
        "--noise", type=float, default=0.002, help="noise std, fraction of the GT diagonal"
    )
    ap.add_argument("--outliers", type=float, default=0.02, help="outlier fraction")
    ap.add_argument("--refine-seconds", type=float, default=300.0, help="refinement time budget")
    ap.add_argument("--threads", type=int, default=2, help="torch threads of the refinement")
    ap.add_argument(
        "--smooth-iterations",
        type=int,
        help="mesh.cleanup.smooth_iterations (default: the config default)",
    )
    ap.add_argument(
        "--smooth-boundary",
        choices=BOUNDARY_MODES,
        help="mesh.cleanup.smooth_boundary (default: the config default)",
    )
    ap.add_argument("--workspace", help="a dense workspace in the GT frame (real pipeline)")
    ap.add_argument("--gt-dir", help="the dataset's gt/ folder (with --workspace)")
    ap.add_argument(
        "--holdout-every", type=int, default=5, help="held-out view stride (with --workspace)"
    )
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--log", action="store_true", help="log the stages' progress to stderr")
    args = ap.parse_args()
    if args.log:
        setup_logging()
    out = run_workspace(args) if args.workspace else run_synthetic(args)
    print_report(out)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
