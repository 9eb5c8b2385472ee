"""The ``ingest`` stage: a real recording in any supported format -> the canonical event file,
plus the side data the recording carries, in our results layout.

Outputs (the folders are always created, so that a Snakemake rule can declare them; what they
hold is listed in the manifest):

- ``events_out``: the canonical event file (:mod:`evdense.events.container`);
- ``conventional_dir/frames/``: the recording's conventional (APS) frames as ``000000.png ...``
  with ``timestamps.txt`` (``index t_seconds``), when it has frames;
- ``gt_dir/intrinsics.yaml`` and ``gt_dir/cameras.txt``: the camera (from the calibration file
  given, else from the recording), when known;
- ``gt_dir/trajectory.txt``: the ground-truth trajectory (TUM, camera-to-world), when present;
- ``gt_dir/mesh.ply``: the ground-truth surface, when given as a mesh (``gt_mesh``) or as depth
  maps fused with the GT poses (``gt_depth``, :mod:`evdense.io.gt_depth`);
- ``manifest_out``: JSON listing the above (``null`` for what was not found), the sensor size and
  where it came from, counts, and every correction the validation made.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from evdense.camera import Camera, load_camera
from evdense.config import section_from_dict
from evdense.errors import as_input_error
from evdense.events.container import EventWriter
from evdense.formats.files import write_atomic, write_json_atomic
from evdense.formats.frames import frame_name, write_timestamps
from evdense.io.base import DEFAULT_CHUNK_EVENTS, Recording
from evdense.io.detect import open_recording
from evdense.io.validate import (
    ValidationConfig,
    ValidationReport,
    check_sensor_size,
    infer_sensor_size,
    validate_stream,
)
from evdense.log import get_logger, progress
from evdense.poses import read_tum, write_tum

log = get_logger("io")


@dataclass
class IngestConfig:
    """Reading real recordings into the canonical event file (config section ``ingest``)."""

    chunk_events: int = DEFAULT_CHUNK_EVENTS
    """Events per batch read from the recording (bounds memory: ~30 bytes per event)."""
    unsorted: Literal["sort", "error"] = "sort"
    """Out-of-order timestamps: `sort` re-orders them within `reorder_window_us` (the count is
    logged and recorded in the ingest manifest); `error` stops at the first step back in time."""
    reorder_window_us: int = 10_000
    """How far back in time (microseconds) an event may arrive and still be sorted into place; an
    event further behind is an error. Memory for sorting is the event rate times this window."""
    out_of_bounds: Literal["error", "drop"] = "error"
    """Events outside the sensor size; `error` stops naming the event, `drop` drops them and logs
    the count."""
    time_unit: Literal["auto", "s", "ms", "us", "ns"] = "auto"
    """Unit of timestamps for formats that do not fix it (RPG text, E2VID HDF5, NumPy). auto: a
    decimal point in text means seconds; floats are seconds, integers microseconds."""
    write_frames: bool = True
    """Copy the recording's conventional (APS) frames to results/{dataset}/conventional/frames/."""
    compression: Literal["blosc-lz4", "zstd", "gzip", "lzf", "none"] = "blosc-lz4"
    """HDF5 compression of the canonical event file. blosc-lz4 (about 4 bytes per event, read at
    over 100 M events/s; other HDF5 tools need the hdf5plugin filters), zstd (smaller), gzip and lzf
    (readable by any h5py, slower), none (13 bytes per event)."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> IngestConfig:
        """Build from the ``ingest`` section; unknown keys are an error naming them."""
        return section_from_dict(cls, d, "ingest")

    def validation(self) -> ValidationConfig:
        return ValidationConfig(
            unsorted=self.unsorted,
            reorder_window_us=int(self.reorder_window_us),
            out_of_bounds=self.out_of_bounds,
        )


@dataclass
class IngestResult:
    """What :func:`ingest_recording` wrote and found (also written as the manifest JSON)."""

    recording: str
    format: str
    events: str
    num_events: int
    width: int
    height: int
    sensor_size_source: str
    t_start_us: int
    t_end_us: int
    frames: str | None = None
    num_frames: int = 0
    intrinsics: str | None = None
    cameras_txt: str | None = None
    intrinsics_source: str | None = None
    trajectory: str | None = None
    num_poses: int = 0
    trajectory_source: str | None = None
    gt_mesh: str | None = None
    gt_mesh_source: str | None = None
    """The GT surface given (``gt_mesh``), or the depth maps it was fused from (``gt_depth``)."""
    corrections: list[str] = field(default_factory=list)
    validation: dict[str, Any] = field(default_factory=dict)
    reader: dict[str, Any] = field(default_factory=dict)


def _sensor_size(
    rec: Recording, width: int | None, height: int | None, calibration: Camera | None
) -> tuple[int, int, str]:
    if (width is None) != (height is None):
        raise ValueError(f"{rec.path}: give both width and height, or neither")
    if rec.width is not None or rec.height is not None:
        check_sensor_size(rec.width, rec.height, rec.path, "stated by the file")
    file_size = (rec.width, rec.height) if rec.width and rec.height else None
    if width is not None and height is not None:
        if file_size and file_size != (width, height):
            log.warning(
                "%s: the file says %dx%d but the config says %dx%d; using the config",
                rec.path,
                *file_size,
                width,
                height,
            )
        return (*check_sensor_size(width, height, rec.path, "given in the config"), "config")
    if file_size:
        return file_size[0], file_size[1], "file"
    if calibration is not None:
        log.info(
            "%s: sensor size %dx%d from the calibration",
            rec.path,
            calibration.width,
            calibration.height,
        )
        w, h = check_sensor_size(calibration.width, calibration.height, rec.path, "calibration")
        return w, h, "calibration"
    w, h = check_sensor_size(*infer_sensor_size(rec.iter_events(), rec.path), rec.path,
                             "inferred from the coordinates")  # fmt: skip
    log.warning(
        "%s: the file does not state its sensor size; inferred %dx%d from the largest coordinates "
        "(set the dataset's width/height to be sure)",
        rec.path,
        w,
        h,
    )
    return w, h, "inferred"


def _load_calibration(path: str | Path, width: int | None, height: int | None) -> Camera:
    """Our YAML / Kalibr-VINS YAML / COLMAP cameras.txt, or an RPG calib.txt (plain numbers)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: calibration file not found")
    text = path.read_text().split()
    try:
        [float(v) for v in text]
        plain = True
    except ValueError:
        plain = False
    if plain:
        if width is None or height is None:
            # size filled in later from the sensor; a placeholder now
            width, height = 0, 0
        from evdense.camera import load_rpg_calib

        return load_rpg_calib(path, width, height)
    return load_camera(path)


def _write_frames(rec: Recording, out_dir: Path) -> int:
    """Write the recording's frames to ``out_dir`` (temp folder, then renamed); returns the count."""
    import imageio.v3 as iio

    tmp = out_dir.with_name(out_dir.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    n = 0
    times_us: list[int] = []
    last = None
    try:
        for fr in rec.iter_frames():
            if n == 0:
                tmp.mkdir(parents=True)
            name = tmp / frame_name(n)
            if fr.source is not None and fr.source.suffix.lower() == ".png":
                shutil.copyfile(fr.source, name)
            else:
                img = fr.image if fr.image is not None else iio.imread(fr.source)
                if img.dtype != np.uint8:
                    raise ValueError(f"{rec.path}: frame {n} is {img.dtype}; expected 8-bit images")
                iio.imwrite(name, img)
            if last is not None and fr.t_us < last:
                log.warning("%s: frame %d is earlier than the frame before it", rec.path, n)
            last = fr.t_us
            times_us.append(int(fr.t_us))
            n += 1
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if n:
        write_timestamps(tmp, range(n), times_us, unit="us")
        shutil.rmtree(out_dir, ignore_errors=True)
        os.replace(tmp, out_dir)
    return n


def import_gt_mesh(src: str | Path, out: Path) -> Path:
    """Copy a ground-truth triangle mesh (any format Open3D reads) to ``out`` (PLY), checked:
    ``ValueError`` naming ``src`` when it holds no triangles or non-finite vertices."""
    import open3d as o3d

    src = Path(src)
    if not src.is_file():
        raise FileNotFoundError(f"{src}: GT mesh not found")
    mesh = o3d.io.read_triangle_mesh(str(src))
    v = np.asarray(mesh.vertices)
    if len(mesh.triangles) == 0:
        raise ValueError(f"{src}: not a triangle mesh (no triangles read); gt_mesh needs a surface")
    if not np.isfinite(v).all():
        raise ValueError(f"{src}: GT mesh has non-finite vertex coordinates")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".partial.ply")
    if not o3d.io.write_triangle_mesh(str(tmp), mesh):
        raise OSError(f"{tmp}: could not write the GT mesh")
    os.replace(tmp, out)
    log.info("%s: GT mesh (%d triangles) -> %s", src, len(mesh.triangles), out)
    return out


def surface_from_gt_depth(gt_depth: str | Path, gt_dir: Path, result: IngestResult) -> Path:
    """Fuse the GT depth maps into ``gt_dir/mesh.ply`` with the GT poses and the camera that the
    ingest wrote to ``gt_dir``; ``ValueError`` naming ``gt_depth`` when either is missing."""
    from evdense.formats.files import atomic_path
    from evdense.io.gt_depth import fuse_depth_maps, read_depth_maps

    if result.trajectory is None or result.intrinsics is None:
        raise ValueError(
            f"{gt_depth}: GT depth needs the GT poses (gt_trajectory, or a recording that holds "
            "them) and a calibration, to be fused into a surface"
        )
    import open3d as o3d

    depth, t = read_depth_maps(gt_depth)
    t_gt, T_gt = read_tum(result.trajectory)
    mesh = fuse_depth_maps(depth, t, load_camera(result.intrinsics), t_gt, T_gt)
    out = gt_dir / "mesh.ply"
    with atomic_path(out, keep_suffix=True) as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh):
            raise OSError(f"{tmp}: could not write the GT surface")
    return out


def ingest_recording(
    recording: str | Path,
    events_out: str | Path,
    conventional_dir: str | Path | None = None,
    gt_dir: str | Path | None = None,
    manifest_out: str | Path | None = None,
    fmt: str = "auto",
    calibration: str | Path | None = None,
    width: int | None = None,
    height: int | None = None,
    config: IngestConfig | None = None,
    reader_options: dict[str, Any] | None = None,
    gt_mesh: str | Path | None = None,
    gt_trajectory: str | Path | None = None,
    gt_depth: str | Path | None = None,
) -> IngestResult:
    """Convert ``recording`` to the canonical event file ``events_out`` and copy its side data.

    ``fmt``: a format name or "auto"; ``width``/``height``: sensor size in pixels (overrides the
    file's; when neither is known it is inferred as max + 1 with a warning); ``calibration``: an
    intrinsics file (our YAML, Kalibr/VINS YAML, COLMAP cameras.txt, RPG calib.txt) that takes
    precedence over calibration stored in the recording. ``conventional_dir``/``gt_dir``/
    ``manifest_out`` are optional (see the module docstring). ``gt_mesh``: the recording's GT
    surface (a triangle mesh in the frame of its GT poses), written to ``gt_dir/mesh.ply``;
    ``gt_trajectory``: a TUM file of GT camera-to-world poses in the recording's clock (seconds),
    which replaces any trajectory the recording holds; ``gt_depth``: GT depth maps (see
    :mod:`evdense.io.gt_depth`), fused with the GT poses and the camera into ``gt_dir/mesh.ply``
    (instead of ``gt_mesh``). Raises ``ValueError`` naming the file and position on bad input; no
    output appears under its final name unless complete.
    """
    if gt_mesh is not None and gt_depth is not None:
        raise ValueError(f"{gt_depth}: give gt_mesh or gt_depth, not both ({gt_mesh})")
    cfg = config or IngestConfig()
    recording = Path(recording)
    events_out = Path(events_out)
    # The events go to a staged name first and get their final name only when the side data
    # (frames, calibration, trajectory) were read too: a failure leaves nothing complete-looking.
    staged = events_out.with_name(events_out.name + ".staged.partial")
    try:
        result = _ingest(recording, events_out, staged, conventional_dir, gt_dir, fmt, calibration,
                         width, height, cfg, reader_options)  # fmt: skip
        if gt_trajectory is not None and gt_dir is not None:
            t_gt, T_gt = read_tum(gt_trajectory)
            if len(t_gt) < 2:
                raise ValueError(f"{gt_trajectory}: a GT trajectory needs at least 2 poses")
            write_atomic(Path(gt_dir) / "trajectory.txt", lambda p: write_tum(p, t_gt, T_gt))
            result.trajectory = str(Path(gt_dir) / "trajectory.txt")
            result.num_poses = len(t_gt)
            result.trajectory_source = str(gt_trajectory)
        if gt_mesh is not None and gt_dir is not None:
            result.gt_mesh = str(import_gt_mesh(gt_mesh, Path(gt_dir) / "mesh.ply"))
            result.gt_mesh_source = str(gt_mesh)
        if gt_depth is not None and gt_dir is not None:
            result.gt_mesh = str(surface_from_gt_depth(gt_depth, Path(gt_dir), result))
            result.gt_mesh_source = str(gt_depth)
    except (KeyboardInterrupt, MemoryError):
        staged.unlink(missing_ok=True)
        raise
    except Exception as e:
        staged.unlink(missing_ok=True)
        for side in (calibration, gt_mesh, gt_trajectory, gt_depth):
            if side and str(Path(side)) in str(e):
                raise as_input_error(Path(side), e) from e
        raise as_input_error(recording, e) from e
    os.replace(staged, events_out)
    if manifest_out is not None:
        write_json_atomic(manifest_out, asdict(result))
    return result


# Over 80 lines on purpose: one pass over an open recording, events then frames, calibration
# and GT, into one staged output; the reader must stay open for all of them.
def _ingest(
    recording: Path,
    events_out: Path,
    staged: Path,
    conventional_dir: str | Path | None,
    gt_dir: str | Path | None,
    fmt: str,
    calibration: str | Path | None,
    width: int | None,
    height: int | None,
    cfg: IngestConfig,
    reader_options: dict[str, Any] | None,
) -> IngestResult:
    cal = _load_calibration(calibration, width, height) if calibration else None
    with open_recording(
        recording,
        fmt,
        chunk_events=cfg.chunk_events,
        time_unit=cfg.time_unit,
        **(reader_options or {}),
    ) as rec:
        w, h, size_src = _sensor_size(
            rec, width, height, cal if cal is not None and cal.width else None
        )
        log.info("%s: format %s, sensor %dx%d (%s)", recording, rec.format, w, h, size_src)
        if cal is not None and cal.width == 0:
            cal = Camera(w, h, cal.fx, cal.fy, cal.cx, cal.cy, cal.dist)
        cam_src = str(calibration) if cal is not None else None
        if cal is None:
            cal = rec.camera(w, h)
            cam_src = f"{rec.path} ({rec.format})" if cal is not None else None
        if cal is not None and (cal.width, cal.height) != (w, h):
            raise ValueError(
                f"{cam_src}: calibration is for a {cal.width}x{cal.height} image but the sensor is {w}x{h}"
            )
        report = ValidationReport()
        attrs: dict[str, Any] = {"source_format": rec.format}
        if cal is not None:
            attrs["camera"] = cal.to_dict()
        provenance = {
            "stage": "ingest",
            "recording": str(recording.resolve()),
            "format": rec.format,
            "sensor_size_source": size_src,
            "reader": rec.metadata,
        }
        batches = validate_stream(rec.iter_events(), rec.path, w, h, cfg.validation(), report)
        t0 = t1 = 0
        with EventWriter(
            staged, w, h, provenance=provenance, attrs=attrs, compression=cfg.compression
        ) as writer:
            for ev in progress(batches, desc=f"ingest {recording.name} (batches)"):
                if writer.num_events == 0:
                    t0 = int(ev.t[0])
                writer.append(ev)
                t1 = int(ev.t[-1])
            n_ev = writer.num_events
        if n_ev == 0:
            log.warning("%s: the recording holds no events", recording)
        log.info(
            "%s: wrote %d events over %.3f s to %s", recording, n_ev, (t1 - t0) * 1e-6, events_out
        )
        result = IngestResult(
            recording=str(recording),
            format=rec.format,
            events=str(events_out),
            num_events=n_ev,
            width=w,
            height=h,
            sensor_size_source=size_src,
            t_start_us=int(t0),
            t_end_us=int(t1),
            corrections=list(report.corrections),
            validation=asdict(report),
            reader={k: v for k, v in rec.metadata.items()},
        )
        if conventional_dir is not None:
            conventional_dir = Path(conventional_dir)
            conventional_dir.mkdir(parents=True, exist_ok=True)
            if cfg.write_frames:
                frames_dir = conventional_dir / "frames"
                nf = _write_frames(rec, frames_dir)
                if nf:
                    result.frames, result.num_frames = str(frames_dir), nf
                    log.info("%s: wrote %d conventional frames to %s", recording, nf, frames_dir)
        if gt_dir is not None:
            gt_dir = Path(gt_dir)
            gt_dir.mkdir(parents=True, exist_ok=True)
            if cal is not None:
                write_atomic(gt_dir / "intrinsics.yaml", cal.write_yaml)
                write_atomic(gt_dir / "cameras.txt", cal.write_colmap_cameras_txt)
                result.intrinsics = str(gt_dir / "intrinsics.yaml")
                result.cameras_txt = str(gt_dir / "cameras.txt")
                result.intrinsics_source = cam_src
            traj = rec.trajectory()
            if traj is not None:
                write_atomic(gt_dir / "trajectory.txt", lambda p: write_tum(p, traj.t, traj.T_wc))
                result.trajectory = str(gt_dir / "trajectory.txt")
                result.num_poses = len(traj.t)
                result.trajectory_source = traj.source
                log.info(
                    "%s: wrote %d ground-truth poses to %s",
                    recording,
                    len(traj.t),
                    result.trajectory,
                )
    return result
