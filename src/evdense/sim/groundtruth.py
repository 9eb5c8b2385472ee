"""Ground truth of a simulated dataset, written to ``results/{dataset}/gt/``.

Contents: ``mesh.ply`` (world frame, metres), ``trajectory.txt`` (TUM, camera-to-world, sampled at
``simulator.render.gt_pose_rate_hz``), ``intrinsics.yaml`` and ``cameras.txt`` (COLMAP),
``frames/`` (sharp images at the conventional camera's frame timestamps, i.e. the middle of its
exposures, or at ``simulator.render.gt_min_frames`` evenly spaced times when the conventional
camera takes fewer, see :func:`gt_frame_times`; 8-bit PNG, log tone-mapped, + ``timestamps.txt``
with lines ``index t_seconds``),
``intensity.h5`` (``intensity`` ``(N, H, W)``
float32 linear radiance, ``t`` ``(N,)`` seconds), ``depth.h5`` (``depth`` ``(N, H, W)`` float32
z-depth in metres, 0 = no surface, ``t``), ``scene.json`` (the resolved scene, from which
:func:`render_gt_intensity` re-renders any timestamp).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import imageio.v3 as iio
import numpy as np

from evdense.formats.frames import frame_name, write_timestamps
from evdense.log import get_logger, progress
from evdense.poses import write_tum
from evdense.sim.render import Renderer
from evdense.sim.scene import Scene, load_scene, scene_from_resolved

log = get_logger("sim.groundtruth")

DEFAULT_FRAME_RATE_HZ = 20.0


def frame_timestamps(duration_s: float, fps: float) -> np.ndarray:
    """Frame times ``i / fps`` (seconds) from 0 up to and including ``duration_s``, ``(N,)``."""
    n = int(np.floor(duration_s * fps + 1e-9)) + 1
    return np.arange(n, dtype=np.float64) / fps


def conventional_frame_times(duration_s: float, sim_conf: dict) -> tuple[np.ndarray, float]:
    """The conventional camera's frame timestamps (seconds, middle of each exposure, as written by
    :mod:`evdense.sim.conventional`) over a recording of ``duration_s``, and its frame rate (Hz)
    from ``simulator.conventional_camera`` (default 20 Hz). ``ValueError`` names a bad key."""
    section = (sim_conf or {}).get("conventional_camera") or {}
    try:
        from evdense.sim.conventional import ConventionalCameraConfig, frame_times
    except ImportError:  # pragma: no cover - the conventional camera ships with the package
        fps = float(section.get("fps", DEFAULT_FRAME_RATE_HZ))
        if not fps > 0:
            raise ValueError(f"simulator.conventional_camera.fps: must be > 0, got {fps}") from None
        return frame_timestamps(duration_s, fps), fps
    conf = ConventionalCameraConfig.from_dict(section)
    times = frame_times(duration_s, conf) + conf.exposure / 2.0
    if len(times) == 0:
        raise ValueError(
            f"simulator.conventional_camera: recording of {duration_s} s is shorter than one exposure"
        )
    return times, float(conf.fps)


def gt_frame_times(duration_s: float, sim_conf: dict, min_frames: int) -> tuple[np.ndarray, float]:
    """Times (seconds) of the GT frames, the oracle's images, and their mean rate (Hz).

    The conventional camera's frame times (so that GT and conventional frames pair one to one)
    when it takes at least ``min_frames`` frames; otherwise ``min_frames`` times evenly spaced from
    0 to ``duration_s``. Under fast motion a 20 Hz camera takes a handful of frames while the event
    camera gives dozens of windows; an oracle limited to that handful is no upper bound.
    """
    times, fps = conventional_frame_times(duration_s, sim_conf)
    if len(times) >= min_frames:
        return times, fps
    times = np.linspace(0.0, duration_s, min_frames)
    return times, (min_frames - 1) / duration_s if duration_s > 0 else fps


def tonemap_log(radiance: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """8-bit log tone-mapping: ``log(radiance)`` from ``log(lo)`` .. ``log(hi)`` to 0 .. 255
    (clipped), so that an HDR scene keeps detail in both its dark and bright parts."""
    llo, lhi = np.log(lo), np.log(hi)
    v = (np.log(np.maximum(radiance, 1e-30)) - llo) / max(lhi - llo, 1e-9)
    return np.clip(np.round(v * 255.0), 0, 255).astype(np.uint8)


def write_groundtruth(dataset_conf: dict, sim_conf: dict, out_dir: Path) -> None:
    """Build the dataset's scene and write its ground truth into ``out_dir`` (see module docstring).

    ``dataset_conf``: one entry of ``config["datasets"]``; ``sim_conf``: ``config["simulator"]``
    (reads ``render`` and ``conventional_camera``, whose frame rate, default 20 Hz, and exposure set
    the frame timestamps, so that GT and conventional frames pair one to one, unless the camera
    takes fewer than ``render.gt_min_frames``: see :func:`gt_frame_times`). The folder is
    assembled under ``<out_dir>.partial`` and renamed at the end, so a failed run leaves no complete-looking output.
    Raises ``ValueError`` naming the key on a bad configuration, before anything is written.
    """
    out_dir = Path(out_dir)
    sim_conf = sim_conf or {}
    scene = load_scene(dataset_conf, sim_conf)
    times, fps = gt_frame_times(scene.trajectory.duration, sim_conf, scene.render.gt_min_frames)

    tmp = out_dir.with_name(out_dir.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "frames").mkdir(parents=True)
    try:
        cam = scene.camera
        scene.write_mesh(tmp / "mesh.ply")
        t_pose, poses = scene.trajectory.sample(scene.render.gt_pose_rate_hz)
        write_tum(tmp / "trajectory.txt", t_pose, poses)
        cam.write_yaml(tmp / "intrinsics.yaml")
        cam.write_colmap_cameras_txt(tmp / "cameras.txt")
        (tmp / "scene.json").write_text(json.dumps(scene.resolved(), indent=1))

        n, H, W = len(times), cam.height, cam.width
        renderer = Renderer(scene)
        log.info(
            "%s: rendering %d ground-truth frames at %.1f Hz (%dx%d)", scene.name, n, fps, W, H
        )
        attrs = {"time_unit": "s", "width": W, "height": H, "scene": scene.name}
        with (
            h5py.File(tmp / "intensity.h5", "w") as fi,
            h5py.File(tmp / "depth.h5", "w") as fd,
        ):
            di = fi.create_dataset("intensity", (n, H, W), np.float32, chunks=(1, H, W))
            dd = fd.create_dataset(
                "depth",
                (n, H, W),
                np.float32,
                chunks=(1, H, W),
                compression="gzip",
                compression_opts=1,
            )
            fi.create_dataset("t", data=times)
            fd.create_dataset("t", data=times)
            fi.attrs.update({**attrs, "units": "linear radiance (relative)"})
            fd.attrs.update(
                {**attrs, "units": "z-depth along the optical axis, metres; 0 = no surface"}
            )
            for i, t in progress(
                enumerate(times), total=n, desc=f"gt frames {scene.name}", logger=log
            ):
                out = renderer.render(scene.trajectory.pose(t))
                di[i] = out.radiance
                dd[i] = out.depth
            # one tone curve for the whole sequence, from log-radiance percentiles of a subsample
            sub = di[:: max(1, n // 40), ::2, ::2]
            lo, hi = np.percentile(sub, scene.render.gt_tonemap_percentiles)
            hi = max(hi, lo * 1.01)
            fi.attrs["tonemap_lo_hi"] = [float(lo), float(hi)]
            for i in range(n):
                iio.imwrite(tmp / "frames" / frame_name(i), tonemap_log(di[i], lo, hi))
        write_timestamps(tmp / "frames", range(len(times)), times)

    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)  # never leave a half-written folder behind
        raise
    if out_dir.exists():
        shutil.rmtree(out_dir)
    tmp.rename(out_dir)
    log.info("%s: ground truth written to %s", scene.name, out_dir)


def render_gt_intensity(
    scene_or_gt_dir: Scene | str | Path, timestamps_s: np.ndarray
) -> np.ndarray:
    """Sharp linear radiance ``(N, H, W)`` float32 at any recording times ``timestamps_s`` ``(N,)``
    (seconds), from a :class:`Scene` or a ground-truth folder (its ``scene.json``)."""
    if isinstance(scene_or_gt_dir, Scene):
        scene = scene_or_gt_dir
    else:
        path = Path(scene_or_gt_dir)
        scene = scene_from_resolved(path / "scene.json" if path.is_dir() else path)
    renderer = Renderer(scene)
    ts = np.atleast_1d(np.asarray(timestamps_s, dtype=np.float64))
    out = np.empty((len(ts), scene.camera.height, scene.camera.width), np.float32)
    for i, t in enumerate(ts):
        out[i] = renderer.radiance_at(t)
    return out
