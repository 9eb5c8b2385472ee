"""The evaluation stage: one image source of one dataset against its ground truth.

Monocular SfM recovers the scene up to a similarity, so everything is first aligned to the GT:
Umeyama Sim(3) on camera centres matched by timestamp, then a scaled ICP of the densest cloud onto
the GT surface, accepted only when it brings the cloud closer (a truncated squared distance
falls). The aligned products (sparse cloud, dense cloud, meshes) are cropped to the GT volume and
scored with :mod:`evdense.evaluate.geometry`; the trajectory with
:mod:`evdense.evaluate.trajectory_errors`; the frames with :mod:`evdense.evaluate.images` against GT
intensity rendered at their timestamps.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d

from evdense.config import section_from_dict
from evdense.evaluate.align import align_trajectory_to_gt, apply_sim3
from evdense.evaluate.geometry import (
    bbox_diagonal,
    evaluate_geometry,
    observed_surface_samples,
    sample_surface,
)
from evdense.evaluate.images import compare_to_gt
from evdense.evaluate.trajectory_errors import evaluate_trajectory
from evdense.formats.cloud import read_cloud
from evdense.formats.files import write_json_atomic
from evdense.formats.frames import frame_paths_and_times
from evdense.log import get_logger
from evdense.poses import read_tum

log = get_logger("evaluate")


@dataclass
class EvalConfig:
    """Settings of the evaluation (config section ``evaluate``)."""

    relative_thresholds: list[float] = field(default_factory=lambda: [0.0025, 0.005, 0.01, 0.02])
    """Distance thresholds of precision, recall and F-score, as fractions of the GT bounding-box
    diagonal."""
    default_threshold: float = 0.01
    """The threshold (one of the above) reported as *the* F-score in tables and plots."""
    curve_thresholds: list[float] = field(
        default_factory=lambda: [round(float(r), 6) for r in np.geomspace(0.001, 0.05, 23)]
    )
    """Thresholds (fractions of the GT diagonal) of the precision/recall/F curves stored beside
    the scores (``geometry.<product>.curve``) and drawn in ``prf_vs_threshold``."""
    num_samples: int = 200_000
    """GT surface samples for completeness (and samples of each reconstructed mesh)."""
    completeness_reference: str = "observed"
    """GT surface that completeness (recall) is measured on: observed (the part seen by at least
    visibility_min_views of visibility_views GT cameras spread along the whole trajectory, the same
    for every image source of a dataset) or full (the whole GT mesh, walls never looked at
    included)."""
    visibility_views: int = 60
    """GT cameras, evenly spaced in time along the trajectory, that define the observed surface."""
    visibility_min_views: int = 2
    """A GT surface point is observed when at least this many of those cameras see it (unoccluded,
    in the image)."""
    crop_margin: float = 0.02
    """Reconstructions are cropped to the GT bounding box grown by this fraction of its diagonal."""
    icp: bool = True
    """Refine the Sim(3) from camera centres with a scaled ICP onto the GT surface."""
    icp_max_distance: float = 0.02
    """ICP correspondence distance, as a fraction of the GT bounding-box diagonal."""
    icp_max_points: int = 200_000
    """ICP runs on a random subset of at most this many cloud points (0 = all): an event-frame
    cloud of 1.7 M points took 53 s in ICP alone, for a transform a subset fixes as well."""
    image_mode: str = "histogram"
    """How frames (of any tone curve) meet GT radiance before MSE, PSNR and SSIM: histogram (GT
    log-mapped to [0, 1], the frame's grey levels matched to its histogram: structure is compared,
    not tone curve) or percentile (each rescaled by its 1st-99th percentiles)."""
    max_image_frames: int = 60
    """At most this many frames (evenly spaced) of a source are compared with GT intensity."""
    heldout_views: int = 10
    """Renders of the textured mesh from this many held-out GT cameras (midway between GT frame
    times, which no conventional or GT frame uses) are compared with GT images."""
    figures: bool = True
    """Draw each dataset's pictures (``results/{dataset}/figures/``, the seed paper's figures and
    the error-coloured views) and its page of textured meshes (``results/{dataset}/meshes.html``)."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> EvalConfig:
        return section_from_dict(cls, d, "evaluate")

    def check(self) -> None:
        if self.completeness_reference not in ("observed", "full"):
            raise ValueError(
                "evaluate.completeness_reference: observed or full, "
                f"not {self.completeness_reference!r}"
            )


def gt_reference_samples(
    gt_dir: Path, gt_mesh: o3d.geometry.TriangleMesh, conf: EvalConfig
) -> tuple[np.ndarray | None, dict[str, Any]]:
    """The GT points completeness is measured on, and a description of them for the metrics file.

    ``observed``: :func:`~evdense.evaluate.geometry.observed_surface_samples` from
    ``visibility_views`` GT cameras evenly spaced in time over ``gt_dir/trajectory.txt``;
    ``full``: None (the whole surface, sampled by :func:`evaluate_geometry`).
    """
    if conf.completeness_reference == "full":
        return None, {"kind": "full", "num_samples": conf.num_samples}
    from evdense.camera import load_camera
    from evdense.poses import interpolate_poses

    t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
    times = np.linspace(t_gt.min(), t_gt.max(), conf.visibility_views)
    _, poses = interpolate_poses(times, t_gt, T_gt)
    cam = load_camera(gt_dir / "intrinsics.yaml")
    pts, frac = observed_surface_samples(
        gt_mesh, cam, poses, conf.num_samples, conf.visibility_min_views, seed=1
    )
    if len(pts) == 0:
        raise ValueError(f"{gt_dir}: the GT cameras see no part of the GT mesh")
    log.info(
        "observed GT surface: %.1f%% of the mesh area (%d samples, >= %d of %d views)",
        100 * frac, len(pts), conf.visibility_min_views, conf.visibility_views,
    )  # fmt: skip
    info = {
        "kind": "observed",
        "num_samples": len(pts),
        "observed_area_fraction": frac,
        "views": conf.visibility_views,
        "min_views": conf.visibility_min_views,
    }
    return pts, info


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


def truncated_cost(fitness: float, inlier_rmse: float, max_distance: float) -> float:
    """Mean of ``min(d, max_distance)^2`` over the points of a registration whose inliers (a
    ``fitness`` fraction, within ``max_distance``) have RMSE ``inlier_rmse``: one number that
    weighs points lost to the threshold against inliers brought closer."""
    return fitness * inlier_rmse**2 + (1.0 - fitness) * max_distance**2


def refine_with_icp(
    points: np.ndarray,
    gt_mesh: o3d.geometry.TriangleMesh,
    max_distance: float,
    seed: int = 0,
    max_points: int = 0,
) -> tuple[np.ndarray, dict[str, float]]:
    """Scaled point-to-point ICP of ``points (N, 3)`` (already roughly aligned) onto GT surface samples.

    Returns the 4x4 similarity to apply after the first alignment, and the fitness / RMSE before
    and after. ICP is accepted when it lowers the truncated cost (:func:`truncated_cost`), the
    identity is returned otherwise: a correction that brings 99.99 % of the cloud 10 % closer is
    kept even when a handful of far points leave the threshold. With ``max_points`` > 0, ICP and
    both scores use a random subset of that many points (seeded).
    """
    if 0 < max_points < len(points):
        rng = np.random.default_rng(seed)
        points = points[np.sort(rng.choice(len(points), max_points, replace=False))]
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    dst = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(sample_surface(gt_mesh, 200_000, seed))
    )
    reg = o3d.pipelines.registration
    before = reg.evaluate_registration(src, dst, max_distance)
    est = reg.TransformationEstimationPointToPoint(with_scaling=True)
    crit = reg.ICPConvergenceCriteria(max_iteration=50)
    H = np.asarray(
        reg.registration_icp(src, dst, max_distance, np.eye(4), est, crit).transformation
    )
    after = reg.evaluate_registration(src, dst, max_distance, H)
    cost_before = truncated_cost(before.fitness, before.inlier_rmse, max_distance)
    cost_after = truncated_cost(after.fitness, after.inlier_rmse, max_distance)
    info = {
        "num_points": len(points),
        "fitness_before": float(before.fitness),
        "rmse_before": float(before.inlier_rmse),
        "fitness_after": float(after.fitness),
        "rmse_after": float(after.inlier_rmse),
        "cost_before": float(cost_before),
        "cost_after": float(cost_after),
        "accepted": bool(cost_after < cost_before),
    }
    return (H if info["accepted"] else np.eye(4)), info


def _apply_h(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ H[:3, :3].T + H[:3, 3]


def evaluate_images(frames_dir: Path, gt_dir: Path, conf: EvalConfig) -> dict[str, Any]:
    """MSE, PSNR and SSIM of a frames folder against GT intensity rendered at the frames' times."""
    import imageio.v3 as iio

    from evdense.sim.groundtruth import render_gt_intensity

    paths, ts = frame_paths_and_times(frames_dir)
    if not paths:
        return {"num_frames": 0}
    pick = np.unique(
        np.linspace(0, len(paths) - 1, min(conf.max_image_frames, len(paths))).round().astype(int)
    )
    gt = render_gt_intensity(gt_dir, ts[pick])
    per = []
    for k, i in enumerate(pick):
        img = iio.imread(paths[i]).astype(np.float64)
        if img.ndim == 3:
            img = img[..., :3].mean(-1)
        per.append(compare_to_gt(img, gt[k], conf.image_mode))
    out = {k: float(np.mean([m[k] for m in per])) for k in ("mse", "psnr", "ssim")}
    out["num_frames"] = len(per)
    return out


# Over 80 lines on purpose: the order of the evaluation (SfM, alignment, trajectory, images,
# geometry), each a call; what remains is which score needs which product and the metrics' shape.
def evaluate_source(
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
            obj = _apply_h(H, obj) if len(obj) else obj
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


def alignment_record(
    s: float, R: np.ndarray, t: np.ndarray, icp: np.ndarray | None = None
) -> dict[str, Any]:
    """How the SfM frame was mapped onto GT: the Sim(3) from camera centres (``x -> s R x + t``)
    and the ICP refinement applied after it (4x4; identity without a GT surface)."""
    return {
        "scale": s,
        "R": np.asarray(R).tolist(),
        "t": np.asarray(t).tolist(),
        "icp": (np.eye(4) if icp is None else np.asarray(icp)).tolist(),
    }


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


def evaluate_against_reference(
    frames_dir: Path, reference_dir: Path, conf: EvalConfig, max_shift: int = 10
) -> dict[str, Any]:
    """MSE and SSIM of frames against the recording's nearest APS frame (EVREAL-style: each image
    rescaled by its 1st-99th percentiles, best integer shift within ``max_shift`` px; see
    :func:`evdense.evaluate.real_frames.shifted_metrics`). Reference frames more than half the
    median frame interval from every frame are not used."""
    import imageio.v3 as iio

    from evdense.evaluate.real_frames import shifted_metrics

    if frames_dir.resolve() == reference_dir.resolve():
        return {"reference": "aps_nearest", "num_frames": 0, "note": "the source is the reference"}
    paths, ts = frame_paths_and_times(frames_dir)
    ref_paths, ref_ts = frame_paths_and_times(reference_dir)
    out: dict[str, Any] = {"reference": "aps_nearest", "num_frames": 0}
    if not paths or not ref_paths:
        return out
    gap = float(np.median(np.diff(ts))) if len(ts) > 1 else np.inf
    pairs = []
    for j, tr in enumerate(ref_ts):
        i = int(np.argmin(np.abs(ts - tr)))
        if abs(ts[i] - tr) <= gap / 2:
            pairs.append((i, j))
    if len(pairs) > conf.max_image_frames:
        keep = np.linspace(0, len(pairs) - 1, conf.max_image_frames).round().astype(int)
        pairs = [pairs[k] for k in np.unique(keep)]
    per = []
    for i, j in pairs:
        img = iio.imread(paths[i]).astype(np.float64)
        ref = iio.imread(ref_paths[j]).astype(np.float64)
        img = img[..., :3].mean(-1) if img.ndim == 3 else img
        ref = ref[..., :3].mean(-1) if ref.ndim == 3 else ref
        if img.shape != ref.shape:
            continue
        per.append(shifted_metrics(img, ref, max_shift))
    if per:
        out.update({k: float(np.mean([m[k] for m in per])) for k in ("mse", "ssim")})
    out["num_frames"] = len(per)
    return out


def evaluate_textured(
    obj_path: Path,
    sim3: tuple[float, np.ndarray, np.ndarray],
    H: np.ndarray,
    gt_dir: Path,
    conf: EvalConfig,
) -> dict[str, Any]:
    """PSNR and SSIM of the textured mesh rendered from held-out GT cameras against GT images.

    The mesh is moved into the GT frame (Sim(3) then ICP); GT cameras sit midway between the GT
    frame times. Scores are over the pixels the mesh covers, after matching the render's grey
    levels to the GT log image (as for frames); ``coverage`` is that pixel fraction.
    """
    from skimage.exposure import match_histograms

    from evdense.camera import load_camera
    from evdense.evaluate.images import log_reference
    from evdense.evaluate.rendering import render_textured
    from evdense.sim.groundtruth import render_gt_intensity
    from evdense.texture import read_textured_mesh

    tm = read_textured_mesh(obj_path)
    s, R, t = sim3
    v = apply_sim3(s, R, t, tm.vertices)
    tm.vertices = _apply_h(H, v)
    cam = load_camera(gt_dir / "intrinsics.yaml")
    frame_t = frame_paths_and_times(gt_dir / "frames")[1]
    mids = (frame_t[:-1] + frame_t[1:]) / 2
    if len(mids) == 0:
        return {"num_views": 0}
    mids = mids[
        np.unique(
            np.linspace(0, len(mids) - 1, min(conf.heldout_views, len(mids))).round().astype(int)
        )
    ]
    t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
    from evdense.poses import interpolate_poses

    _, poses = interpolate_poses(mids, t_gt, T_gt)
    gt = render_gt_intensity(gt_dir, mids)
    psnr, ssim, cover = [], [], []
    for k in range(len(mids)):
        img, mask = render_textured(tm, cam, poses[k])
        cover.append(float(mask.mean()))
        if mask.sum() < 100:
            continue
        grey = img[..., :3].mean(-1) if img.ndim == 3 else img
        ref = log_reference(gt[k])
        matched = np.clip(match_histograms(grey[mask].astype(np.float64), ref[mask]), 0, 1)
        mse = float(np.mean((matched - ref[mask]) ** 2))
        psnr.append(10 * np.log10(1 / mse) if mse > 0 else float("inf"))
        full = ref.copy()
        full[mask] = matched
        from skimage.metrics import structural_similarity

        ssim.append(float(structural_similarity(full, ref, data_range=1.0)))
    return {
        "num_views": len(mids),
        "psnr": float(np.mean(psnr)) if psnr else 0.0,
        "ssim": float(np.mean(ssim)) if ssim else 0.0,
        "coverage": float(np.mean(cover)),
    }


def _f_at(geom: dict, rel: float) -> float | None:
    for r, f in zip(geom["relative_thresholds"], geom["fscore"], strict=True):
        if abs(r - rel) < 1e-12:
            return round(f, 4)
    return None
