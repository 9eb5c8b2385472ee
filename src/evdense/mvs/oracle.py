"""The oracle check of the stereo: a COLMAP model from ground truth (poses, intrinsics, depth),
so that MVS runs without SfM, and the evaluation of its output against the ground truth.

:func:`build_gt_model` writes a COLMAP sparse model whose cameras and poses are the simulator's
(``results/{dataset}/gt/``: ``intrinsics.yaml``, ``trajectory.txt`` interpolated at the frame
times, ``frames/``, ``depth.h5``) and whose sparse points are samples of the GT depth maps, with
tracks from a depth test in every other frame (so that source-view selection and depth ranges work
as on an SfM model). :func:`evaluate_mvs` measures the fused cloud (precision and recall at a
distance threshold) and the depth maps (median error against GT depth).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from scipy.spatial import cKDTree

from evdense.camera import Camera, load_camera
from evdense.formats.cloud import read_cloud
from evdense.formats.files import write_json_atomic
from evdense.formats.frames import read_frames
from evdense.log import get_logger
from evdense.mvs.maps_io import read_colmap_array
from evdense.poses import interpolate_poses, invert_pose, read_tum

log = get_logger("mvs")


@dataclass
class OracleConfig:
    """How the ground-truth model of the oracle check is built."""

    max_frames: int = 60
    """Frames used (evenly spaced over the sequence); 0 = all."""
    point_grid_step: int = 16
    """Sparse points: one GT depth sample every this many pixels in each frame."""
    depth_tolerance: float = 0.01
    """A point is visible in another frame when its depth there matches the GT depth within this
    relative tolerance."""


def write_known_model(
    sparse_dir: str | Path,
    camera: Camera,
    names: list[str],
    poses: np.ndarray,
    points: np.ndarray,
    tracks: list[np.ndarray],
) -> Path:
    """Write a COLMAP model of known cameras: one ``camera`` (evdense convention; written in
    COLMAP's, +0.5 px), images ``names`` with camera-to-world ``poses`` ``(N, 4, 4)``, and points
    ``(M, 3)`` observed by the image indices ``tracks[m]`` (keypoints are their projections)."""
    import pycolmap

    sparse_dir = Path(sparse_dir)
    sparse_dir.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    if camera.has_distortion:
        model, params = (
            "OPENCV",
            [camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5, *camera.dist],
        )
    else:
        model, params = "PINHOLE", [camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5]
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(
            camera_id=1, model=model, width=camera.width, height=camera.height, params=params
        )
    )
    # keypoints per image: projections of the points it observes
    per_image: list[list[int]] = [[] for _ in names]
    for m, tr in enumerate(tracks):
        for i in tr:
            per_image[int(i)].append(m)
    slot: dict[tuple[int, int], int] = {}
    for i, name in enumerate(names):
        T_cw = invert_pose(np.asarray(poses[i], np.float64))
        ids = per_image[i]
        if ids:
            Xc = points[ids] @ T_cw[:3, :3].T + T_cw[:3, 3]
            uv = camera.project(Xc) + 0.5
        else:
            uv = np.zeros((0, 2))
        for k, m in enumerate(ids):
            slot[(i, m)] = k
        im = pycolmap.Image(name=name, keypoints=uv.astype(np.float64), camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(
            im, pycolmap.Rigid3d(pycolmap.Rotation3d(T_cw[:3, :3]), T_cw[:3, 3].copy())
        )
    for m, tr in enumerate(tracks):
        elems = [pycolmap.TrackElement(int(i) + 1, slot[(int(i), m)]) for i in tr]
        rec.add_point3D(np.asarray(points[m], np.float64), pycolmap.Track(elems))
    rec.write(str(sparse_dir))
    return sparse_dir


def _read_gt(gt_dir: Path) -> tuple[Camera, list[str], np.ndarray, np.ndarray]:
    for f in ("intrinsics.yaml", "trajectory.txt", "depth.h5", "frames"):
        if not (gt_dir / f).exists():
            raise ValueError(f"{gt_dir / f}: missing from the ground-truth folder")
    cam = load_camera(gt_dir / "intrinsics.yaml")
    frames = read_frames(gt_dir / "frames")
    names, times = [f.name for f in frames], np.array([f.t for f in frames])
    t, T = read_tum(gt_dir / "trajectory.txt")
    return cam, names, times, interpolate_poses(np.clip(times, t.min(), t.max()), t, T)[1]


def sample_tracks(
    depths: np.ndarray, camera: Camera, poses: np.ndarray, step: int, tolerance: float
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Sparse points from GT depth maps ``(N, H, W)`` (one sample every ``step`` pixels per frame)
    and their tracks: the frames where the point projects inside and the GT depth agrees within
    ``tolerance`` (relative). Points seen by fewer than two frames are dropped."""
    N, H, W = depths.shape
    rays = camera.pixel_rays()
    pts = []
    for i in range(N):
        d = depths[i, step // 2 :: step, step // 2 :: step]
        r = rays[step // 2 :: step, step // 2 :: step]
        ok = d > 0
        Xc = r[ok] * d[ok][:, None]
        pts.append(Xc @ poses[i][:3, :3].T + poses[i][:3, 3])
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    seen = np.zeros((len(P), N), bool)
    for j in range(N):
        T_cw = invert_pose(poses[j])
        Xc = P @ T_cw[:3, :3].T + T_cw[:3, 3]
        front = Xc[:, 2] > 1e-6
        uv = np.full((len(P), 2), -1.0)
        uv[front] = camera.project(Xc[front])
        u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        inside = front & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        dj = np.zeros(len(P))
        dj[inside] = depths[j][v[inside], u[inside]]
        seen[:, j] = (
            inside & (dj > 0) & (np.abs(dj - Xc[:, 2]) <= tolerance * np.maximum(Xc[:, 2], 1e-9))
        )
    keep = seen.sum(1) >= 2
    return P[keep], [np.nonzero(s)[0] for s in seen[keep]]


def build_gt_model(
    gt_dir: str | Path, sparse_dir: str | Path, config: OracleConfig | None = None
) -> Path:
    """Write the oracle's COLMAP model (see the module docstring) into ``sparse_dir``; the images
    it names are those of ``gt_dir/frames``. Raises ``ValueError`` naming a missing GT file."""
    cfg = config or OracleConfig()
    gt_dir = Path(gt_dir)
    cam, names, _, poses = _read_gt(gt_dir)
    n = len(names)
    sel = np.arange(n)
    if cfg.max_frames and n > cfg.max_frames:
        sel = np.unique(np.round(np.linspace(0, n - 1, cfg.max_frames)).astype(int))
    with h5py.File(gt_dir / "depth.h5", "r") as f:
        if "depth" not in f or f["depth"].shape[0] != n:
            raise ValueError(f"{gt_dir / 'depth.h5'}: expected dataset 'depth' with {n} frames")
        depths = np.stack([f["depth"][int(i)] for i in sel]).astype(np.float32)
    P, tracks = sample_tracks(depths, cam, poses[sel], cfg.point_grid_step, cfg.depth_tolerance)
    sparse_dir = Path(sparse_dir)
    tmp = sparse_dir.with_name(sparse_dir.name + ".partial")
    if tmp.exists():
        import shutil

        shutil.rmtree(tmp)
    write_known_model(tmp, cam, [names[i] for i in sel], poses[sel], P, tracks)
    if sparse_dir.exists():
        import shutil

        shutil.rmtree(sparse_dir)
    tmp.rename(sparse_dir)
    log.info(
        "oracle model: %d frames, %d sparse points from GT depth -> %s",
        len(sel),
        len(P),
        sparse_dir,
    )
    return sparse_dir


def _mesh_distance(mesh_path: Path, points: np.ndarray) -> tuple[np.ndarray, float]:
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(mesh_path))
    if len(mesh.triangles) == 0:
        raise ValueError(f"{mesh_path}: no triangles in the GT mesh")
    diag = float(np.linalg.norm(mesh.get_max_bound() - mesh.get_min_bound()))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    d = (
        scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()
        if len(points)
        else np.zeros(0)
    )
    return d.astype(np.float64), diag


def evaluate_mvs(
    mvs_dir: str | Path, gt_dir: str | Path, threshold: float = 0.005
) -> dict[str, Any]:
    """Evaluate an MVS folder made with GT poses (the oracle) against ``gt_dir``.

    ``threshold``: distance threshold as a fraction of the GT mesh's bounding-box diagonal.
    precision: fraction of fused points within the threshold of the GT mesh; recall: fraction of
    the observed GT surface (the GT depth maps of the workspace's views, back-projected and
    thinned to one point per threshold/2 voxel) within the threshold of a fused point; per map:
    median relative and absolute depth error of the kept pixels against GT depth, and the kept
    fraction of the pixels with GT depth.
    """
    from evdense.mvs.workspace import read_workspace

    mvs_dir, gt_dir = Path(mvs_dir), Path(gt_dir)
    ws = read_workspace(mvs_dir)
    cloud = read_cloud(mvs_dir / "fused.ply", read_vis=False, allow_empty=True)
    dist, diag = _mesh_distance(gt_dir / "mesh.ply", cloud.points)
    tau = threshold * diag
    names = [f.name for f in read_frames(gt_dir / "frames")]
    index = {nm: k for k, nm in enumerate(names)}
    maps = []
    gt_pts = []
    with h5py.File(gt_dir / "depth.h5", "r") as f:
        for im in ws.images:
            if im.name not in index:
                continue
            gt = f["depth"][index[im.name]].astype(np.float64)
            if gt.shape != (im.height, im.width):
                continue
            rays = np.stack(
                [*np.meshgrid(np.arange(im.width), np.arange(im.height)), np.ones_like(gt)], -1
            )
            rays = rays.reshape(-1, 3) @ np.linalg.inv(im.K).T
            ok = gt.reshape(-1) > 0
            Xc = rays[ok] * gt.reshape(-1)[ok][:, None]
            gt_pts.append((Xc - im.t) @ im.R)
            p = ws.map_path("depth", im.name, "geometric")
            if not p.is_file():
                continue
            d = read_colmap_array(p).astype(np.float64)
            m = (d > 0) & (gt > 0)
            rec: dict[str, Any] = {
                "name": im.name,
                "kept_fraction": float(m.sum() / max((gt > 0).sum(), 1)),
            }
            if m.any():
                rec["median_rel_error"] = float(np.median(np.abs(d[m] - gt[m]) / gt[m]))
                rec["median_abs_error"] = float(np.median(np.abs(d[m] - gt[m])))
            maps.append(rec)
    G = np.concatenate(gt_pts) if gt_pts else np.zeros((0, 3))
    if len(G):
        _, first = np.unique(np.floor(G / (tau / 2)).astype(np.int64), axis=0, return_index=True)
        G = G[first]
    recall = 0.0
    if len(G) and len(cloud):
        dd, _ = cKDTree(cloud.points).query(G, k=1)
        recall = float((dd <= tau).mean())
    rel = [m["median_rel_error"] for m in maps if "median_rel_error" in m]
    absr = [m["median_abs_error"] for m in maps if "median_abs_error" in m]
    result = {
        "threshold_rel": threshold,
        "threshold_m": tau,
        "bbox_diagonal_m": diag,
        "fused_points": len(cloud),
        "gt_surface_points": len(G),
        "precision": float((dist <= tau).mean()) if len(dist) else 0.0,
        "recall": recall,
        "accuracy_median_m": float(np.median(dist)) if len(dist) else None,
        "depth_median_rel_error": float(np.median(rel)) if rel else None,
        "depth_median_abs_error_m": float(np.median(absr)) if absr else None,
        "depth_kept_fraction": float(np.median([m["kept_fraction"] for m in maps]))
        if maps
        else 0.0,
        "maps": maps,
    }
    p, r = result["precision"], result["recall"]
    result["fscore"] = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return result


def write_evaluation(path: str | Path, result: dict[str, Any]) -> None:
    """Write an evaluation dict as JSON (atomically)."""
    write_json_atomic(path, result, indent=1, default=None)
