"""The evaluation stage: one image source of one dataset against its ground truth.

Monocular SfM recovers the scene up to a similarity, so everything is first aligned to the GT:
Umeyama Sim(3) on camera centres matched by timestamp, then a scaled ICP of the densest cloud onto
the GT surface, accepted only when it brings the cloud closer (a truncated squared distance
falls). The aligned products (sparse cloud, dense cloud, meshes) are cropped to the GT volume and
scored with :mod:`evdense.evaluate.geometry_metrics`; the trajectory with
:mod:`evdense.evaluate.trajectory_errors`; the frames with :mod:`evdense.evaluate.images` against GT
intensity rendered at their timestamps.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d

from evdense.evaluate.align import (
    align_trajectory_to_gt,
    alignment_record,
    apply_h,
    apply_sim3,
    refine_with_icp,
)
from evdense.evaluate.config import EvalConfig
from evdense.evaluate.geometry_metrics import (
    bbox_diagonal,
    evaluate_geometry,
    gt_reference_samples,
)
from evdense.evaluate.images import evaluate_against_reference, evaluate_images, evaluate_textured
from evdense.evaluate.trajectory_errors import evaluate_trajectory
from evdense.formats.cloud import read_cloud
from evdense.formats.files import write_json_atomic
from evdense.log import get_logger
from evdense.poses import read_tum

log = get_logger("evaluate")


def _read_cloud(path: Path) -> np.ndarray:
    return read_cloud(path, read_vis=False, allow_empty=True).points


def _read_mesh(path: Path) -> o3d.geometry.TriangleMesh:
    return o3d.io.read_triangle_mesh(str(path))


def _sparse_points(sfm_dir: Path) -> np.ndarray:
    import pycolmap

    model = sfm_dir / "sparse" / "0"
    if not model.is_dir():
        return np.zeros((0, 3))
    rec = pycolmap.Reconstruction(str(model))
    return np.array([p.xyz for p in rec.points3D.values()], dtype=np.float64).reshape(-1, 3)


def _transform_mesh(mesh: o3d.geometry.TriangleMesh, s: float, R: np.ndarray, t: np.ndarray):
    out = o3d.geometry.TriangleMesh(mesh)
    out.vertices = o3d.utility.Vector3dVector(apply_sim3(s, R, t, np.asarray(mesh.vertices)))
    return out


# Over 80 lines on purpose: the order of the evaluation (SfM, alignment, trajectory, images,
# geometry), each a call; what remains is which score needs which product and the metrics' shape.
def run_evaluate(
    gt_dir: str | Path,
    sfm_dir: str | Path,
    out_path: str | Path,
    frames_dir: str | Path | None = None,
    dense_cloud: str | Path | None = None,
    meshes: dict[str, str | Path] | None = None,
    conf: EvalConfig | dict | None = None,
    labels: dict[str, Any] | None = None,
    reference_frames: str | Path | None = None,
) -> dict[str, Any]:
    """Score one image source of a dataset against GT and write ``out_path`` (JSON).

    A synthetic dataset's ``gt/`` holds everything (trajectory, mesh, intensity). A recording's
    holds what it carries: the trajectory (ATE and RPE after Sim(3), matched by time) is scored
    when ``gt/trajectory.txt`` exists, geometry when ``gt/mesh.ply`` does, and its frames, when
    ``reference_frames`` (the recording's APS frames) is given, against the nearest APS frame
    (:func:`evaluate_against_reference`, marked ``"reference": "aps_nearest"``).

    Args:
        gt_dir: the dataset's ``gt/`` folder (``trajectory.txt``, ``mesh.ply``, ``scene.json``).
        sfm_dir: the SfM output folder (``trajectory.txt``, ``stats.json``, ``sparse/0``).
        frames_dir: the frames the SfM ran on (image metrics; skipped when None).
        dense_cloud: the fused dense cloud PLY (skipped when None or missing).
        meshes: named mesh PLY/OBJ files (e.g. ``{"mesh_visibility": ..., "refined": ...}``).
        labels: extra fields copied into the JSON (dataset, source, speed, ...).
    """
    conf = conf if isinstance(conf, EvalConfig) else EvalConfig.from_dict(conf)
    gt_dir, sfm_dir, out_path = Path(gt_dir), Path(sfm_dir), Path(out_path)
    result: dict[str, Any] = {"labels": labels or {}, "config": asdict(conf)}
    stats_path = sfm_dir / "stats.json"
    sfm_stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
    result["sfm"] = {
        k: sfm_stats.get(k)
        for k in (
            "num_frames",
            "num_selected",
            "num_registered",
            "registered_fraction",
            "num_points3D",
            "mean_track_length",
            "mean_reprojection_error_px",
        )
    }
    if not all((gt_dir / f).is_file() for f in ("mesh.ply", "trajectory.txt", "intrinsics.yaml")):
        return _evaluate_without_gt_geometry(gt_dir, sfm_dir, out_path, frames_dir, conf,
                                             result, sfm_stats, reference_frames)  # fmt: skip
    gt_mesh = o3d.io.read_triangle_mesh(str(gt_dir / "mesh.ply"))
    diag = bbox_diagonal(gt_mesh)
    gt_samples, result["gt_reference"] = gt_reference_samples(gt_dir, gt_mesh, conf)
    if sfm_stats.get("failed"):
        # A failed SfM is a result: nothing was reconstructed, every F-score is 0.
        log.warning(
            "%s: SfM failed (%s); recording an empty reconstruction",
            sfm_dir,
            sfm_stats.get("error"),
        )
        result["failed"] = True
        result["error"] = sfm_stats.get("error")
        empty = evaluate_geometry(
            np.zeros((0, 3)),
            gt_mesh,
            conf.relative_thresholds,
            1000,
            gt_samples=gt_samples,
            curve_thresholds=conf.curve_thresholds,
        ).to_dict()
        result["geometry"] = {name: empty for name in ["sparse", "dense", *(meshes or {})]}
        return _with_images(result, out_path, frames_dir, reference_frames, gt_dir, conf)
    t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
    traj_path = sfm_dir / "trajectory.txt"
    if not traj_path.exists():
        raise ValueError(f"{sfm_dir}: no trajectory.txt (did SfM finish?)")
    t_est, T_est = read_tum(traj_path)
    traj = evaluate_trajectory(t_est, T_est, t_gt, T_gt)
    result["trajectory"] = traj.to_dict()
    ce = align_trajectory_to_gt(t_est, T_est, t_gt, T_gt)
    s, R, t = ce.scale, ce.R, ce.t

    aligned = _aligned_products(sfm_dir, dense_cloud, meshes, s, R, t)

    H = np.eye(4)
    ref = (
        aligned.get("dense") if "dense" in aligned and len(aligned["dense"]) else aligned["sparse"]
    )
    if conf.icp and len(ref) >= 100:
        H, info = refine_with_icp(
            ref, gt_mesh, conf.icp_max_distance * diag, max_points=conf.icp_max_points
        )
        result["icp"] = info
    result["alignment"] = alignment_record(s, R, t, H)

    textured = (meshes or {}).get("textured")
    if textured and Path(textured).exists() and (gt_dir / "scene.json").is_file():
        # rendered against GT intensity, which only a synthetic scene has
        result["textured_renders"] = evaluate_textured(Path(textured), (s, R, t), H, gt_dir, conf)
    result["geometry"] = _geometry_scores(aligned, H, gt_mesh, gt_samples, conf)
    return _with_images(result, out_path, frames_dir, reference_frames, gt_dir, conf)


def _aligned_products(
    sfm_dir: Path,
    dense_cloud: str | Path | None,
    meshes: dict[str, str | Path] | None,
    s: float,
    R: np.ndarray,
    t: np.ndarray,
) -> dict[str, Any]:
    """The sparse points, the dense cloud and the meshes that exist (not the textured one,
    which is scored by its renders), mapped into the GT frame by ``x -> s R x + t``."""
    products: dict[str, Any] = {"sparse": _sparse_points(sfm_dir)}
    if dense_cloud is not None and Path(dense_cloud).exists():
        products["dense"] = _read_cloud(Path(dense_cloud))
    for name, p in (meshes or {}).items():
        if name != "textured" and Path(p).exists():
            products[name] = _read_mesh(Path(p))
    aligned: dict[str, Any] = {}
    for name, obj in products.items():
        if isinstance(obj, np.ndarray):
            aligned[name] = apply_sim3(s, R, t, obj) if len(obj) else obj
        else:
            aligned[name] = _transform_mesh(obj, s, R, t)
    return aligned


def _geometry_scores(
    aligned: dict[str, Any],
    H: np.ndarray,
    gt_mesh: o3d.geometry.TriangleMesh,
    gt_samples: np.ndarray | None,
    conf: EvalConfig,
) -> dict[str, Any]:
    """Accuracy, completeness, P/R/F and Chamfer of each aligned product after the ICP ``H``."""
    geometry = {}
    for name, obj in aligned.items():
        if isinstance(obj, np.ndarray):
            obj = apply_h(H, obj) if len(obj) else obj
        else:
            obj.transform(H)
        m = evaluate_geometry(
            obj,
            gt_mesh,
            conf.relative_thresholds,
            conf.num_samples,
            conf.crop_margin,
            gt_samples=gt_samples,
            curve_thresholds=conf.curve_thresholds,
        )
        geometry[name] = m.to_dict()
        log.info(
            "%s: %d points, F@%.2g%% = %s",
            name,
            m.num_points,
            100 * conf.default_threshold,
            _f_at(m.to_dict(), conf.default_threshold),
        )
    return geometry


def _with_images(
    result: dict[str, Any],
    out_path: Path,
    frames_dir: str | Path | None,
    reference_frames: str | Path | None,
    gt_dir: Path,
    conf: EvalConfig,
) -> dict[str, Any]:
    """Add the image figures of ``frames_dir`` (against the GT frames, or against
    ``reference_frames`` when given) to ``result``, and write it to ``out_path``."""
    if frames_dir is not None and reference_frames is None:
        result["images"] = evaluate_images(Path(frames_dir), gt_dir, conf)
    elif frames_dir is not None:
        result["images"] = evaluate_against_reference(
            Path(frames_dir), Path(reference_frames), conf
        )
    write_json_atomic(out_path, result, default=float)
    return result


def _evaluate_without_gt_geometry(
    gt_dir: Path,
    sfm_dir: Path,
    out_path: Path,
    frames_dir: str | Path | None,
    conf: EvalConfig,
    result: dict[str, Any],
    sfm_stats: dict[str, Any],
    reference_frames: str | Path | None,
) -> dict[str, Any]:
    """A recording without a GT surface: the trajectory and the frames, whatever it carries."""
    result["geometry"] = {}
    if sfm_stats.get("failed"):
        log.warning("%s: SfM failed (%s)", sfm_dir, sfm_stats.get("error"))
        result["failed"] = True
        result["error"] = sfm_stats.get("error")
    elif (gt_dir / "trajectory.txt").is_file():
        t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
        traj_path = sfm_dir / "trajectory.txt"
        if not traj_path.exists():
            raise ValueError(f"{sfm_dir}: no trajectory.txt (did SfM finish?)")
        t_est, T_est = read_tum(traj_path)
        result["trajectory"] = evaluate_trajectory(t_est, T_est, t_gt, T_gt).to_dict()
        ce = align_trajectory_to_gt(t_est, T_est, t_gt, T_gt)
        result["alignment"] = alignment_record(ce.scale, ce.R, ce.t)  # for the figures
        log.info("%s: trajectory against %s: %s", sfm_dir, gt_dir / "trajectory.txt",
                 {k: result["trajectory"].get(k) for k in ("ate_rmse", "ate_rmse_relative")})  # fmt: skip
    if frames_dir is not None and reference_frames is not None:
        result["images"] = evaluate_against_reference(
            Path(frames_dir), Path(reference_frames), conf
        )
    write_json_atomic(out_path, result, default=float)
    return result


def _f_at(geom: dict, rel: float) -> float | None:
    for r, f in zip(geom["relative_thresholds"], geom["fscore"], strict=True):
        if abs(r - rel) < 1e-12:
            return round(f, 4)
    return None
