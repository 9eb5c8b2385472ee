"""The SfM stage: :func:`run_sfm` on a frames folder, the failed-SfM record, the trajectory reader."""

from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evdense.camera import Camera, load_camera
from evdense.formats.files import write_json_atomic
from evdense.formats.frames import Frame, read_frames, resolve_frames_dir
from evdense.log import get_logger
from evdense.poses import invert_pose, write_tum
from evdense.sfm.config import SfmConfig, SfmError
from evdense.sfm.options import set_options
from evdense.sfm.select import select_frames

log = get_logger("sfm")


# ---- the stage --------------------------------------------------------------------------------
def _device(cfg: SfmConfig):
    import pycolmap

    if cfg.device == "cuda" and not pycolmap.has_cuda:
        raise ValueError(
            "config key 'sfm.device': 'cuda' requested but this pycolmap was built without CUDA"
        )
    use_cuda = cfg.device == "cuda" or (cfg.device == "auto" and pycolmap.has_cuda)
    return (pycolmap.Device.cuda if use_cuda else pycolmap.Device.cpu), use_cuda


def _calibrated_camera(cfg: SfmConfig, width: int, height: int) -> Camera:
    cam = load_camera(cfg.calibration_file)
    if (cam.width, cam.height) != (width, height):
        factor = width / cam.width
        if abs(height / cam.height - factor) > 1e-3 * factor:
            raise ValueError(
                f"{cfg.calibration_file}: calibration is {cam.width}x{cam.height}, frames are {width}x{height} "
                "(different aspect ratio; cannot rescale)"
            )
        log.warning(
            "calibration %dx%d rescaled to the frames' %dx%d", cam.width, cam.height, width, height
        )
        cam = cam.scaled(factor)
    return cam


def _colmap_params(cam: Camera) -> tuple[str, list[float]]:
    """COLMAP model and parameters of an evdense camera (principal point shifted by +0.5 px)."""
    return cam.colmap_model()


def _image_size(path: Path) -> tuple[int, int]:
    import imageio.v3 as iio

    props = iio.improps(path)
    h, w = props.shape[:2]
    return int(w), int(h)


def _database_diagnostics(database_path: Path, min_inliers: int) -> dict[str, Any]:
    """Features per image and matched / verified pairs, read back from the COLMAP database."""
    import pycolmap

    db = pycolmap.Database.open(database_path)
    try:
        images = db.read_all_images()
        kp = {im.name: int(db.num_keypoints_for_image(im.image_id)) for im in images}
        pair_ids, tvgs = db.read_two_view_geometries()
        bad = {
            pycolmap.TwoViewGeometryConfiguration.UNDEFINED,
            pycolmap.TwoViewGeometryConfiguration.DEGENERATE,
            pycolmap.TwoViewGeometryConfiguration.WATERMARK,
        }
        inliers = [len(g.inlier_matches) for g in tvgs if g.config not in bad]
        verified = int(sum(n >= min_inliers for n in inliers))
        per_image_verified = {im.name: 0 for im in images}
        id_to_name = {im.image_id: im.name for im in images}
        for pid, g in zip(pair_ids, tvgs, strict=True):
            if g.config in bad or len(g.inlier_matches) < min_inliers:
                continue
            a, b = pycolmap.pair_id_to_image_pair(pid)
            for i in (a, b):
                if i in id_to_name:
                    per_image_verified[id_to_name[i]] += 1
        counts = np.array(list(kp.values()) or [0])
        return {
            "num_images": len(images),
            "features_per_image": {
                "min": int(counts.min()),
                "median": float(np.median(counts)),
                "max": int(counts.max()),
            },
            "features": kp,
            "matched_pairs": int(db.num_matched_image_pairs()),
            "verified_pairs": verified,
            "verified_pairs_min_inliers": min_inliers,
            "inliers_per_verified_pair_median": float(np.median(inliers)) if inliers else 0.0,
            "images_without_verified_pair": sorted(
                n for n, c in per_image_verified.items() if c == 0
            ),
        }
    finally:
        db.close()


def _write_pairs_file(path: Path, names: list[str], keyframe_every: int) -> int:
    keys = names[::keyframe_every]
    if keys[-1] != names[-1]:
        keys.append(names[-1])
    lines = [f"{a} {b}" for i, a in enumerate(keys) for b in keys[i + 1 :]]
    path.write_text("\n".join(lines) + "\n")
    return len(lines)


def _trajectory(rec, by_name: dict[str, Frame]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Registered frames' timestamps (s), camera-to-world poses ``(N, 4, 4)`` and names, in time order."""
    rows = []
    for im in rec.images.values():
        if not im.has_pose:
            continue
        T_cw = np.eye(4)
        T_cw[:3, :] = im.cam_from_world().matrix()
        rows.append((by_name[im.name].t, invert_pose(T_cw), im.name))
    rows.sort(key=lambda r: r[0])
    if not rows:
        return np.zeros(0), np.zeros((0, 4, 4)), []
    return np.array([r[0] for r in rows]), np.stack([r[1] for r in rows]), [r[2] for r in rows]


def _camera_stats(rec) -> dict[str, Any]:
    cam = next(iter(rec.cameras.values()))
    out: dict[str, Any] = {
        "model": cam.model_name,
        "width": int(cam.width),
        "height": int(cam.height),
        "params_colmap": [float(p) for p in cam.params],
        "params_info": cam.params_info,
        "focal_length_x": float(cam.focal_length_x),
        "focal_length_y": float(cam.focal_length_y),
        "focal_length": float(cam.mean_focal_length()),
        "cx": float(cam.principal_point_x) - 0.5,
        "cy": float(cam.principal_point_y) - 0.5,
    }
    if len(rec.cameras) > 1:
        out["num_cameras"] = len(rec.cameras)
    return out


@dataclass
class _Options:
    """The pycolmap option objects of one run."""

    device: Any
    use_cuda: bool
    threads: int
    extraction: Any
    matching: Any
    verification: Any
    pairing: Any
    mapping: Any
    reader: Any
    fixed_intrinsics: bool


def _pycolmap_options(cfg: SfmConfig, threads: int, width: int, height: int) -> _Options:
    """Build pycolmap's option objects: our settings first, then the config's pass-through dicts
    (which win). Raises ``ValueError`` naming the key of a bad option."""
    import pycolmap

    device, use_cuda = _device(cfg)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.use_gpu = use_cuda
    extraction.sift.max_num_features = int(cfg.max_features)
    set_options(extraction, cfg.extraction, "sfm.extraction")

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    matching.use_gpu = use_cuda
    set_options(matching, cfg.matching, "sfm.matching")

    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = cfg.seed
    set_options(verification, cfg.verification, "sfm.verification")

    if cfg.matcher == "exhaustive":
        pairing = pycolmap.ExhaustivePairingOptions()
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.num_threads = threads
    set_options(pairing, cfg.pairing, "sfm.pairing")

    reader = pycolmap.ImageReaderOptions()
    fixed = False
    if cfg.calibration_file:
        cam = _calibrated_camera(cfg, width, height)
        model, params = _colmap_params(cam)
        reader.camera_model = model
        reader.camera_params = ",".join(f"{p:.10g}" for p in params)
        fixed = not cfg.refine_intrinsics
        log.info(
            "camera from %s: %s %s (%s)",
            cfg.calibration_file,
            model,
            params,
            "fixed" if fixed else "refined",
        )
    else:
        reader.camera_model = cfg.camera_model

    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = threads
    mapping.random_seed = cfg.seed
    if fixed:
        mapping.ba_refine_focal_length = False
        mapping.ba_refine_principal_point = False
        mapping.ba_refine_extra_params = False
        mapping.mapper.abs_pose_refine_focal_length = False
        mapping.mapper.abs_pose_refine_extra_params = False
    set_options(mapping, cfg.mapping, "sfm.mapping")
    return _Options(
        device,
        use_cuda,
        threads,
        extraction,
        matching,
        verification,
        pairing,
        mapping,
        reader,
        fixed,
    )


def _match(database: Path, names: list[str], cfg: SfmConfig, opts: _Options, work: Path) -> None:
    import pycolmap

    if cfg.matcher == "exhaustive":
        log.info("matching exhaustively: %d pairs", len(names) * (len(names) - 1) // 2)
        pycolmap.match_exhaustive(
            database, opts.matching, opts.pairing, opts.verification, device=opts.device
        )
        return
    log.info("matching sequentially (overlap %d)", opts.pairing.overlap)
    pycolmap.match_sequential(
        database, opts.matching, opts.pairing, opts.verification, device=opts.device
    )
    if cfg.loop_closure and len(names) > 2:
        pairs_path = work / "loop_pairs.txt"
        n_pairs = _write_pairs_file(pairs_path, names, cfg.loop_keyframe_every)
        log.info("loop closure: matching %d keyframe pairs", n_pairs)
        imported = pycolmap.ImportedPairingOptions()
        imported.match_list_path = pairs_path
        pycolmap.match_image_pairs(
            database, opts.matching, imported, opts.verification, device=opts.device
        )


def _map(
    database: Path, frames_dir: Path, mapper_dir: Path, opts: _Options, n_images: int
) -> list[Any]:
    """Incremental mapping with bundle adjustment; returns the models, largest first."""
    import pycolmap

    state = {"n": 0, "last": time.monotonic()}

    def on_next_image() -> None:
        state["n"] += 1
        now = time.monotonic()
        if now - state["last"] >= 10.0:
            state["last"] = now
            log.info("mapping: %d registration steps (%d frames selected)", state["n"], n_images)

    mapper_dir.mkdir()
    recs = pycolmap.incremental_mapping(
        database, frames_dir, mapper_dir, opts.mapping, next_image_callback=on_next_image
    )
    return sorted(recs.values(), key=lambda r: r.num_reg_images(), reverse=True)


# About 80 lines: the stage's order (frames, features, matching, mapping, model, stats), each a call.
def run_sfm(
    frames_dir: str | Path,
    out_dir: str | Path,
    config: SfmConfig | dict[str, Any] | None = None,
    num_threads: int | None = None,
) -> dict[str, Any]:
    """Run pycolmap SfM on a frames folder and write the model folder ``out_dir`` (see module doc).

    Args:
        frames_dir: folder with ``<index:06d>.png`` and ``timestamps.txt`` (or its parent holding
            ``frames/``).
        out_dir: output folder, replaced when it exists; built as ``<out_dir>.partial``.
        config: :class:`SfmConfig` or the ``sfm`` config section.
        num_threads: overrides ``config.num_threads`` (Snakemake's ``threads``).

    Returns the statistics written to ``stats.json``. Raises :class:`SfmError` when fewer than
    ``min_registered_images`` or ``min_registered_fraction`` of the selected frames register,
    ``ValueError`` on a bad frames folder or option (before anything is written).
    """
    cfg = config if isinstance(config, SfmConfig) else SfmConfig.from_dict(config)
    cfg.check()
    threads = int(num_threads if num_threads is not None else cfg.num_threads)
    frames_dir = resolve_frames_dir(frames_dir)
    out_dir = Path(out_dir)
    frames = read_frames(frames_dir)
    width, height = _image_size(frames_dir / frames[0].name)
    opts = _pycolmap_options(cfg, threads, width, height)  # a bad option fails before any work

    work = out_dir.with_name(out_dir.name + ".partial")
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    times: dict[str, float] = {}

    t0 = time.perf_counter()
    selected = select_frames(frames, frames_dir, cfg)
    times["select_s"] = time.perf_counter() - t0
    names = [f.name for f in selected]
    by_name = {f.name: f for f in selected}
    (work / "selected_frames.txt").write_text(
        "# index name t_seconds (frames given to SfM)\n"
        + "".join(f"{f.index} {f.name} {f.t:.9f}\n" for f in selected)
    )
    log.info(
        "%s: %d frames (%dx%d), %d selected (%s)",
        frames_dir,
        len(frames),
        width,
        height,
        len(selected),
        cfg.select,
    )

    models, diagnostics = _reconstruct(frames_dir, work, names, cfg, opts, threads, times)
    rec = _largest_model(models, frames_dir, work, names, cfg, opts, diagnostics, times)
    n_reg = rec.num_reg_images()

    t0 = time.perf_counter()
    shutil.rmtree(work / "mapper")
    reg_names = _write_model(rec, work, by_name)
    times["write_s"] = time.perf_counter() - t0

    stats = _stats(
        rec, frames, frames_dir, names, reg_names, cfg, opts, threads, times, diagnostics
    )
    write_json_atomic(work / "stats.json", stats)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    work.replace(out_dir)
    log.info(
        "SfM done: %d/%d frames registered, %d points, track length %.2f, reprojection error %.3f px, "
        "f = %.2f px (%.1f s) -> %s",
        n_reg,
        len(names),
        stats["num_points3D"],
        stats["mean_track_length"],
        stats["mean_reprojection_error_px"],
        stats["camera"]["focal_length"],
        stats["time_s"]["total_s"],
        out_dir,
    )
    return stats


def _reconstruct(
    frames_dir: Path,
    work: Path,
    names: list[str],
    cfg: SfmConfig,
    opts: _Options,
    threads: int,
    times: dict[str, float],
) -> tuple[list[Any], dict[str, Any]]:
    """Features, matches and incremental mapping of ``names`` in ``work``: the models, largest
    first, and the database's diagnostics; the steps' seconds go into ``times``."""
    import pycolmap

    database = work / "database.db"
    old_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = getattr(pycolmap.logging, cfg.colmap_log_level)
    pycolmap.set_random_seed(cfg.seed)
    try:
        t0 = time.perf_counter()
        log.info(
            "extracting SIFT features (%s, %d threads)", "cuda" if opts.use_cuda else "cpu", threads
        )
        pycolmap.extract_features(
            database,
            frames_dir,
            image_names=names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=opts.reader,
            extraction_options=opts.extraction,
            device=opts.device,
        )
        times["extract_s"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        _match(database, names, cfg, opts, work)
        times["match_s"] = time.perf_counter() - t0
        diagnostics = _database_diagnostics(database, opts.mapping.min_num_matches)
        log.info(
            "features per image: median %.0f (min %d); verified pairs: %d of %d matched (%.1f s)",
            diagnostics["features_per_image"]["median"],
            diagnostics["features_per_image"]["min"],
            diagnostics["verified_pairs"],
            diagnostics["matched_pairs"],
            times["match_s"],
        )

        t0 = time.perf_counter()
        log.info("incremental mapping and bundle adjustment")
        models = _map(database, frames_dir, work / "mapper", opts, len(names))
        times["map_s"] = time.perf_counter() - t0
    finally:
        pycolmap.logging.minloglevel = old_level
    return models, diagnostics


def _largest_model(
    models: list[Any],
    frames_dir: Path,
    work: Path,
    names: list[str],
    cfg: SfmConfig,
    opts: _Options,
    diagnostics: dict[str, Any],
    times: dict[str, float],
) -> Any:
    """The largest model; :class:`SfmError` (with ``work/diagnostics.json`` written) when it
    registers fewer frames than the config asks."""
    n_reg = models[0].num_reg_images() if models else 0
    needed = max(
        1, cfg.min_registered_images, int(np.ceil(cfg.min_registered_fraction * len(names)))
    )
    diagnostics["models"] = [
        {"registered": r.num_reg_images(), "points": r.num_points3D()} for r in models
    ]
    if n_reg < needed:
        diagnostics.update(
            reason="too few registered frames",
            registered=n_reg,
            selected=len(names),
            needed=needed,
            frames_dir=str(frames_dir),
            config=asdict(cfg),
            time_s=times,
        )
        diag_path = work / "diagnostics.json"
        write_json_atomic(diag_path, diagnostics)
        fpi = diagnostics["features_per_image"]
        message = (
            f"SfM on {frames_dir}: {n_reg} of {len(names)} selected frames registered (need {needed}). "
            f"Features per image: median {fpi['median']:.0f}, min {fpi['min']}; "
            f"verified pairs (>= {opts.mapping.min_num_matches} inliers): {diagnostics['verified_pairs']} of "
            f"{diagnostics['matched_pairs']} matched; {len(diagnostics['images_without_verified_pair'])} frames "
            f"without any verified pair. Diagnostics: {diag_path}"
        )
        log.error(message)
        raise SfmError(message, diag_path)
    if len(models) > 1:
        log.warning(
            "%d models; keeping the largest (%d frames), others: %s",
            len(models),
            n_reg,
            [m.num_reg_images() for m in models[1:]],
        )
    return models[0]


def _write_model(rec: Any, work: Path, by_name: dict[str, Frame]) -> list[str]:
    """The model in ``work``: ``sparse/0`` (binary), ``sparse/0_text``, ``points3D.ply`` and
    ``trajectory.txt``; returns the registered frames' names."""
    model_dir, text_dir = work / "sparse" / "0", work / "sparse" / "0_text"
    model_dir.mkdir(parents=True)
    text_dir.mkdir(parents=True)
    rec.write_binary(model_dir)
    rec.write_text(text_dir)
    rec.export_PLY(work / "points3D.ply")
    t_reg, T_reg, reg_names = _trajectory(rec, by_name)
    write_tum(work / "trajectory.txt", t_reg, T_reg)
    return reg_names


def _stats(
    rec: Any,
    frames: list[Frame],
    frames_dir: Path,
    names: list[str],
    reg_names: list[str],
    cfg: SfmConfig,
    opts: _Options,
    threads: int,
    times: dict[str, float],
    diagnostics: dict[str, Any],
) -> dict[str, Any]:
    """The statistics ``stats.json`` holds."""
    import pycolmap

    n_reg = rec.num_reg_images()
    return {
        "frames_dir": str(frames_dir.resolve()),
        "num_frames": len(frames),
        "num_selected": len(names),
        "num_registered": n_reg,
        "registered_fraction": n_reg / len(names),
        "unregistered": sorted(set(names) - set(reg_names)),
        "num_points3D": rec.num_points3D(),
        "mean_track_length": float(rec.compute_mean_track_length()),
        "mean_observations_per_image": float(rec.compute_mean_observations_per_reg_image()),
        "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
        "camera": _camera_stats(rec),
        "intrinsics_source": cfg.calibration_file or "estimated",
        "intrinsics_fixed": opts.fixed_intrinsics,
        "pixel_convention": "camera.cx/cy: evdense (top-left pixel centre at 0,0); params_colmap: COLMAP (0.5,0.5)",
        "other_models": diagnostics["models"][1:],
        "device": "cuda" if opts.use_cuda else "cpu",
        "num_threads": threads,
        "time_s": {**times, "total_s": sum(times.values())},
        "diagnostics": {k: v for k, v in diagnostics.items() if k not in ("features", "models")},
        "config": asdict(cfg),
        "pycolmap_version": pycolmap.__version__,
    }
