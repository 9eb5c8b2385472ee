"""The pictures of one dataset, from its products on disk (rule ``plot_dataset``).

What the seed paper shows (its Figs. 3-6 and 8-9) and what 3D benchmarks (Tanks and Temples,
ETH3D) show of where a reconstruction is wrong:

- ``events_spacetime``: events of a short span as points in (x, t, y), coloured by polarity;
- ``event_frames``: event frames at four times;
- ``frames``: each source's frames (reconstructed, conventional, GT) at the same times;
- ``reconstructions``: the textured refined mesh and the dense cloud of each source from the same
  viewpoints (a GT camera near the start, one in the middle, and a wide view from the middle),
  the GT mesh beside them, each panel titled with the source and its F-score;
- ``errors_<source>``: the reconstruction coloured by its distance to GT (precision) and the GT
  surface coloured by its distance to the reconstruction (completeness), threshold marked on the
  shared colour bar;
- ``prf_vs_threshold``: precision, recall and F against the threshold for every source;
- ``trajectory``: each source's SfM cameras against GT after the Sim(3) of the evaluation.

With GT (a synthetic scene, or a recording whose evaluation aligned it) everything is drawn in the
GT frame with the evaluation's alignment (``metrics.json``); without it, each source is drawn in
its own SfM frame from its own cameras, and the figures that need GT are skipped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evdense.camera import Camera, load_camera
from evdense.evaluate import figures
from evdense.formats.frames import is_frames_dir
from evdense.log import get_logger
from evdense.poses import read_tum

log = get_logger("figures")


@dataclass
class SourceFiles:
    """The products of one image source of a dataset (any may be missing)."""

    frames: Path | None = None
    sfm: Path | None = None
    dense: Path | None = None
    refined: Path | None = None
    textured: Path | None = None
    metrics: Path | None = None

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SourceFiles:
        return cls(**{k: Path(v) if v else None for k, v in d.items()})


@dataclass
class Loaded:
    """What the figures use of one source, moved into the drawing frame."""

    name: str
    metrics: dict[str, Any]
    transform: np.ndarray | None
    """4x4 similarity from the source's SfM frame to the drawing frame (None: drawn as it is)."""
    t_cam: np.ndarray
    T_cam: np.ndarray
    """The source's SfM camera times and poses (camera-to-world; in the GT frame after the
    trajectory's Sim(3) when there is one, else in the SfM frame)."""
    failed: bool


def alignment_matrix(metrics: dict[str, Any], icp: bool = True) -> np.ndarray | None:
    """The evaluation's map from the SfM frame to GT, 4x4: the Sim(3) from camera centres (what
    the ATE is measured after), then with ``icp`` the scaled ICP onto the GT surface (what the
    geometry is measured after)."""
    a = metrics.get("alignment")
    if not a:
        return None
    S = np.eye(4)
    S[:3, :3] = a["scale"] * np.asarray(a["R"], dtype=np.float64)
    S[:3, 3] = np.asarray(a["t"], dtype=np.float64)
    return np.asarray(a.get("icp", np.eye(4)), dtype=np.float64) @ S if icp else S


def _move_poses(T: np.ndarray, M: np.ndarray | None) -> np.ndarray:
    if M is None or len(T) == 0:
        return T
    s = np.cbrt(np.linalg.det(M[:3, :3]))
    out = np.array(T, dtype=np.float64, copy=True)
    out[:, :3, :3] = (M[:3, :3] / s) @ out[:, :3, :3]
    out[:, :3, 3] = out[:, :3, 3] @ M[:3, :3].T + M[:3, 3]
    return out


def load_source(name: str, files: SourceFiles) -> Loaded:
    metrics = (
        json.loads(files.metrics.read_text()) if files.metrics and files.metrics.is_file() else {}
    )
    M = alignment_matrix(metrics)
    traj = files.sfm / "trajectory.txt" if files.sfm else None
    stats = files.sfm / "stats.json" if files.sfm else None
    failed = bool(stats and stats.is_file() and json.loads(stats.read_text()).get("failed"))
    if traj is not None and traj.is_file() and not failed:
        t, T = read_tum(traj)
    else:
        t, T = np.zeros(0), np.zeros((0, 4, 4))
    T = _move_poses(T, alignment_matrix(metrics, icp=False))
    return Loaded(name, metrics, M, t, T, failed or len(t) == 0)


def source_camera(gt_dir: Path | None, files: SourceFiles) -> Camera | None:
    """The camera to draw with: the GT intrinsics, else the source's SfM camera."""
    if gt_dir is not None and (gt_dir / "intrinsics.yaml").is_file():
        return load_camera(gt_dir / "intrinsics.yaml")
    model = files.sfm / "sparse" / "0" if files.sfm else None
    if (
        model is None
        or not (model / "cameras.bin").is_file()
        and not (model / "cameras.txt").is_file()
    ):
        return None
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    cam = next(iter(rec.cameras.values()))
    return Camera.from_colmap(cam.model.name, cam.width, cam.height, list(cam.params))


def _wide(camera: Camera, factor: float = 0.5) -> Camera:
    """The same sensor with ``factor`` times the focal length (a wider view)."""
    return Camera(
        camera.width, camera.height, camera.fx * factor, camera.fy * factor, camera.cx, camera.cy
    )


def viewpoints(
    t: np.ndarray, T: np.ndarray, camera: Camera
) -> dict[str, tuple[Camera, np.ndarray]]:
    """Name -> (camera, pose): a camera near the start, the middle one, a wide view from the middle."""
    if len(t) == 0:
        return {}
    i0 = int(np.argmin(np.abs(t - (t[0] + 0.1 * (t[-1] - t[0])))))
    im = int(np.argmin(np.abs(t - 0.5 * (t[0] + t[-1]))))
    return {
        "near the start": (camera, T[i0]),
        "middle": (camera, T[im]),
        "wide, from the middle": (_wide(camera), T[im]),
    }


def _read_points(path: Path | None) -> tuple[np.ndarray, np.ndarray | None]:
    from evdense.formats.cloud import read_cloud

    if path is None or not path.is_file():
        return np.zeros((0, 3)), None
    pc = read_cloud(path, read_vis=False, allow_empty=True)
    return pc.points, pc.colors_float()


def _transform(points: np.ndarray, M: np.ndarray | None) -> np.ndarray:
    return points if M is None or len(points) == 0 else points @ M[:3, :3].T + M[:3, 3]


def _f_label(metrics: dict[str, Any], product: str, threshold: float) -> str:
    g = metrics.get("geometry", {}).get(product)
    if not g or not g.get("relative_thresholds"):
        return ""
    rel = np.asarray(g["relative_thresholds"])
    k = int(np.argmin(np.abs(rel - threshold)))
    return f"F@{100 * rel[k]:.2g}% {g['fscore'][k]:.2f}"


def make_dataset_figures(
    dataset: str,
    out_dir: str | Path,
    sources: dict[str, SourceFiles],
    gt_dir: str | Path | None = None,
    events: str | Path | None = None,
    page: str | Path | None = None,
    eval_conf: dict[str, Any] | None = None,
) -> list[Path]:
    """Every picture of one dataset into ``out_dir`` (PNG + PDF), and the mesh page ``page``."""
    import time

    from evdense.evaluate.config import EvalConfig

    t0 = time.monotonic()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    conf = EvalConfig.from_dict(eval_conf)
    gt = Path(gt_dir) if gt_dir is not None and Path(gt_dir).is_dir() else None
    made: list[Path] = []
    if events is not None and Path(events).is_file():
        made += figures.events_spacetime_figure(events, out_dir / "events_spacetime.png", dataset)
        made += figures.event_frames_over_time(events, out_dir / "event_frames.png", dataset)
    frame_dirs = {k: f.frames for k, f in sources.items() if f.frames and is_frames_dir(f.frames)}
    if frame_dirs:
        made += figures.frames_comparison(frame_dirs, out_dir / "frames.png")

    loaded = {k: load_source(k, f) for k, f in sources.items()}
    gt_mesh = None
    has_gt_geometry = gt is not None and (gt / "mesh.ply").is_file()
    if has_gt_geometry:
        import open3d as o3d

        gt_mesh = o3d.io.read_triangle_mesh(str(gt / "mesh.ply"))
    any_files = next(iter(sources.values()), SourceFiles())
    camera = source_camera(gt, any_files)
    if camera is None:
        for f in sources.values():
            camera = camera or source_camera(None, f)
    if camera is not None:
        made += _reconstructions(dataset, out_dir, sources, loaded, gt, gt_mesh, camera, conf)
        if gt_mesh is not None:
            for name in sources:
                made += _errors(
                    name, out_dir, sources[name], loaded[name], gt, gt_mesh, camera, conf
                )
    if gt_mesh is not None:
        made += _prf_curves(out_dir, loaded, conf)
    if gt is not None and (gt / "trajectory.txt").is_file():
        t_gt, T_gt = read_tum(gt / "trajectory.txt")
        tracks = {k: L.T_cam[:, :3, 3] for k, L in loaded.items() if L.transform is not None}
        ates = {
            k: L.metrics.get("trajectory", {}).get("ate_rmse_relative")
            for k, L in loaded.items()
            if L.transform is not None
        }
        made += figures.trajectory_figure(
            T_gt[:, :3, 3], tracks, ates, out_dir / "trajectory.png", dataset
        )
    if page is not None:
        _mesh_page(dataset, Path(page), sources, loaded, gt, camera)
    log.info("%s: %d figure files in %.1f s", dataset, len(made), time.monotonic() - t0)
    return made


def _reconstructions(dataset, out_dir, sources, loaded, gt, gt_mesh, camera, conf) -> list[Path]:
    """Figs. 8-9: the textured refined mesh and the dense cloud of each source, same viewpoints."""
    from evdense.evaluate.rendering import render_mesh, render_points, render_textured
    from evdense.texture import read_textured_mesh

    rows: list[tuple[str, list[tuple[str, np.ndarray | None]]]] = []
    gt_views = None
    if gt is not None and (gt / "trajectory.txt").is_file():
        t, T = read_tum(gt / "trajectory.txt")
        gt_views = viewpoints(t, T, camera)
    for name, files in sources.items():
        L = loaded[name]
        views = (
            gt_views
            if (gt_views and L.transform is not None)
            else viewpoints(L.t_cam, L.T_cam, camera)
        )
        f_mesh = _f_label(L.metrics, "refined", conf.default_threshold)
        f_dense = _f_label(L.metrics, "dense", conf.default_threshold)
        panels: list[tuple[str, np.ndarray | None]] = []
        tm = None
        if not L.failed and files.textured and files.textured.is_file():
            tm = read_textured_mesh(files.textured)
            if L.transform is not None:
                tm.vertices = _transform(tm.vertices, L.transform)
        pts, col = _read_points(files.dense) if not L.failed else (np.zeros((0, 3)), None)
        pts = _transform(pts, L.transform)
        for vname, (cam, T_wc) in (views or {}).items():
            if tm is not None and len(tm.faces):
                img, _ = render_textured(tm, cam, T_wc, background=1.0)
                panels.append((f"textured mesh, {vname}\n{f_mesh}", img))
            else:
                panels.append((f"textured mesh, {vname}\nno model", None))
            if len(pts):
                panels.append(
                    (f"dense cloud, {vname}\n{f_dense}", render_points(pts, cam, T_wc, col, 1, 1.0))
                )
            else:
                panels.append((f"dense cloud, {vname}\nno model", None))
        if not views:
            panels = [("no model", None)]
        rows.append((name, panels))
    if gt_mesh is not None and gt_views:
        panels = []
        for vname, (cam, T_wc) in gt_views.items():
            img = render_mesh(gt_mesh, cam, T_wc, "lambert", background=1.0)
            panels += [(f"GT mesh, {vname}", img), ("", None)]
        rows.append(("GT", panels))
    return figures.panel_grid(rows, out_dir / "reconstructions.png", f"{dataset}: reconstructions")


def distance_view(seen, other, camera: Camera, T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Render mesh ``seen`` and colour it by the distance of each visible point to mesh ``other``:
    distances ``(H, W)`` in metres (NaN where ``seen`` is not hit) and a Lambert shade ``(H, W)``."""
    from evdense.evaluate.geometry_metrics import surface_distance
    from evdense.mesh.geometry import camera_rays, make_scene, raycast_view

    hits = raycast_view(
        make_scene(np.asarray(seen.vertices), np.asarray(seen.triangles)), camera, T_wc
    )
    m = hits.mask
    dist = np.full(m.shape, np.nan)
    shade = np.full(m.shape, np.nan)
    if m.any():
        o, d = camera_rays(camera, T_wc)
        dist[m] = surface_distance(other, o[m] + d[m] * hits.depth[m][:, None])
        dn = d[m] / np.linalg.norm(d[m], axis=1, keepdims=True)
        shade[m] = np.abs(np.einsum("ij,ij->i", hits.normal[m], dn))
    return dist, shade


def _errors(name, out_dir, files, L, gt, gt_mesh, camera, conf) -> list[Path]:
    """The reconstruction coloured by its distance to GT, and GT by its distance to it."""
    import open3d as o3d

    from evdense.evaluate.geometry_metrics import bbox_diagonal

    out_png = out_dir / f"errors_{name}.png"
    mesh_path = files.refined if files.refined and files.refined.is_file() else None
    if L.failed or mesh_path is None:
        return figures.note_figure(f"{name}: SfM failed, no reconstruction to colour", out_png)
    if L.transform is None:
        return figures.note_figure(f"{name}: not aligned to GT (no alignment)", out_png)
    recon = o3d.io.read_triangle_mesh(str(mesh_path))
    if len(recon.triangles) == 0:
        return figures.note_figure(f"{name}: the refined mesh is empty", out_png)
    recon.transform(L.transform)
    tau = conf.default_threshold * bbox_diagonal(gt_mesh)
    t, T = read_tum(gt / "trajectory.txt")
    views = viewpoints(t, T, camera)
    picks = {k: views[k] for k in ("middle", "wide, from the middle")}
    cells = []
    for kind, seen, other in (("precision", recon, gt_mesh), ("completeness", gt_mesh, recon)):
        for vname, (cam, T_wc) in picks.items():
            dist, shade = distance_view(seen, other, cam, T_wc)
            label = (
                "precision: the reconstruction by its distance to GT"
                if kind == "precision"
                else "completeness: GT by its distance to the reconstruction"
            )
            cells.append((f"{label}\n{vname}", dist, shade))
    f_label = _f_label(L.metrics, "refined", conf.default_threshold)
    return figures.error_views(cells, tau, out_png, f"{name}: refined mesh, {f_label}")


def _prf_curves(out_dir, loaded, conf) -> list[Path]:
    """Precision, recall and F of each source's refined mesh against the threshold: the curves
    the evaluation stored beside its scores (``geometry.refined.curve``)."""
    curves, thresholds = {}, None
    for name, L in loaded.items():
        c = (L.metrics.get("geometry", {}).get("refined") or {}).get("curve")
        if not c:
            continue
        if thresholds is None:
            thresholds = np.asarray(c["relative_thresholds"])
        if np.allclose(c["relative_thresholds"], thresholds):
            curves[name] = (c["precision"], c["recall"], c["fscore"])
    if not curves:
        return []
    return figures.prf_figure(
        thresholds, curves, conf.default_threshold, out_dir / "prf_vs_threshold.png"
    )


def _mesh_page(dataset, page, sources, loaded, gt, camera) -> Path:
    """The page of textured meshes, turned together when they share the GT frame."""
    from evdense.evaluate.viewer import PageView, mesh_entry, write_mesh_page
    from evdense.texture import read_textured_mesh

    entries, views = [], {}
    for name, files in sources.items():
        L = loaded[name]
        if L.failed or not (files.textured and files.textured.is_file()):
            continue
        tm = read_textured_mesh(files.textured)
        if len(tm.faces) == 0:
            continue
        tm.vertices = _transform(tm.vertices, L.transform)
        frame = "gt" if L.transform is not None else name
        if frame not in views:
            if frame == "gt" and gt is not None:
                t, T = read_tum(gt / "trajectory.txt")
            else:
                t, T = L.t_cam, L.T_cam
            T_mid = T[int(np.argmin(np.abs(t - 0.5 * (t[0] + t[-1]))))]
            extent = float(np.linalg.norm(np.ptp(tm.vertices, axis=0)))
            depth = np.median((tm.vertices - T_mid[:3, 3]) @ T_mid[:3, 2])
            fov = 2 * np.degrees(np.arctan(0.5 * camera.height / camera.fy)) if camera else 60.0
            views[frame] = PageView.from_pose(
                T_mid, min(100.0, 1.6 * fov), max(depth, 1e-3), extent
            )
        f_label = _f_label(L.metrics, "refined", 0.01)
        entries.append(mesh_entry(tm, f"{name}  {f_label}".strip(), frame))
    return write_mesh_page(
        page,
        entries,
        views,
        title=f"{dataset}: textured meshes",
        notes=(
            "All in the GT frame (the evaluation's alignment), seen first from the middle GT camera."
            if "gt" in views
            else "Each in its own SfM frame, seen first from its middle camera."
        ),
    )
