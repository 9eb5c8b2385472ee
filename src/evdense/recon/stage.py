"""The reconstruction stage (``python -m evdense.recon``): voxel grids (or events) to a folder of intensity frames.

``run_recon(voxel_path, out_dir, conf)`` runs one method over every window of a voxel
file and writes ``out_dir/000000.png, ...`` and ``out_dir/timestamps.txt`` (``index t_seconds``,
the end time of each window). Methods:

- a network (``firenet``, ``firenet_plus``, ``e2vid``, ``ours``, or any name with a checkpoint):
  the checkpoint decides the architecture; the recurrent state is carried from window to window
  and reset where the stream has a gap longer than ``max_gap_s``;
- ``highpass``: the high-pass / complementary filter of Scheerlinck et al. (ACCV 2018) on the
  events themselves (needs ``events_path``), optionally pulled towards conventional frames;
- ``integrate``: direct integration of the events with a small leak (needs ``events_path``).

Baselines output log intensity, which has no absolute scale: they are always rescaled with the
robust min/max ("auto HDR"); for networks that is an option.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from evdense.events.container import EventFile
from evdense.events.voxel import VoxelFile
from evdense.formats.frames import FrameWriter, frame_paths_and_times
from evdense.log import get_logger, progress
from evdense.recon.baselines import LogIntensityFilter
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.config import ReconstructConfig
from evdense.recon.inference import NetworkReconstructor, pick_device
from evdense.recon.postprocess import RobustRescaler, unsharp_mask

log = get_logger("recon")


def _read_reference_frames(frames_dir: str | Path) -> tuple[np.ndarray, list[Path]]:
    """Times (us) and PNG paths of a frames folder (``timestamps.txt``: ``index t_seconds``)."""
    paths, t_s = frame_paths_and_times(frames_dir, allow_empty=True)
    return np.rint(t_s * 1e6).astype(np.int64), paths


def _log_frame(path: Path, shape: tuple[int, int], eps: float = 1.0 / 255) -> np.ndarray:
    from PIL import Image

    img = np.asarray(Image.open(path).convert("L"), dtype=np.float64) / 255.0
    if img.shape != shape:
        raise ValueError(
            f"{path}: frame of size {img.shape}, expected {shape} (the event sensor's)"
        )
    return np.log(img + eps)


# ---------------------------------------------------------------------------------------------
# Methods as frame generators: (t_end_us, image in [0, 1])
# ---------------------------------------------------------------------------------------------


def _network_frames(vox: VoxelFile, conf: ReconstructConfig) -> Iterator[tuple[int, np.ndarray]]:
    if not conf.checkpoint:
        raise ValueError(f"method {conf.method!r} needs a checkpoint")
    ck = load_checkpoint(conf.checkpoint)
    if ck.net.num_bins != vox.bins:
        raise ValueError(
            f"{vox.path}: voxel grids have {vox.bins} bins but {conf.checkpoint} "
            f"({ck.arch}) expects {ck.net.num_bins}"
        )
    rec = NetworkReconstructor(
        ck.net,
        conf.normalize,
        pick_device(conf.device),
        conf.channels_last,
        conf.precision,
        conf.voxel_clip,
    )
    log.info(
        "%s: %s (%d parameters), %d windows of %dx%d, voxel clip %s, normalisation %s, device %s, %s",
        conf.method, ck.arch, ck.net.num_parameters(), vox.num_windows, vox.width, vox.height,
        conf.voxel_clip or "off", rec.normalization, rec.device, conf.precision,
    )  # fmt: skip
    max_gap_us = conf.max_gap_s * 1e6
    resets = 0
    for i in range(vox.num_windows):
        if i > 0 and vox.t_start_us[i] - vox.t_end_us[i - 1] > max_gap_us:
            rec.reset()
            resets += 1
        yield int(vox.t_end_us[i]), rec(vox[i])
    if resets:
        log.info("recurrent state reset at %d gaps longer than %.3f s", resets, conf.max_gap_s)


def _baseline_frames(
    vox: VoxelFile,
    conf: ReconstructConfig,
    events_path: Path,
    reference_dir: Path | None,
) -> Iterator[tuple[int, np.ndarray]]:
    """Filter the events in time order; frame ``k`` is the state at ``t_end_us[k]``.

    Each event is taken in once, even when windows overlap: window ``k`` adds the events from
    where the previous one stopped up to its end index ``i1[k]`` (exclusive).
    """
    ef = EventFile(events_path)
    try:
        if (ef.height, ef.width) != (vox.height, vox.width):
            raise ValueError(
                f"{events_path}: sensor {ef.width}x{ef.height} but {vox.path} has "
                f"{vox.width}x{vox.height} voxel grids"
            )
        if int(vox.i1.max()) > ef.num_events:
            raise ValueError(
                f"{vox.path}: windows reach event {int(vox.i1.max())} but {events_path} holds "
                f"{ef.num_events}; the voxels were made from another event file"
            )
        alpha = conf.cutoff_rad_s if conf.method == "highpass" else conf.leak_rad_s
        pos = int(vox.i0[0])
        t0 = int(vox.t_start_us[0])
        filt = LogIntensityFilter(
            ef.height, ef.width, alpha, conf.contrast_on, conf.contrast_off, t_us=t0
        )
        ref_t, ref_paths = np.zeros(0, np.int64), []
        if reference_dir is not None and conf.method == "highpass" and conf.use_conventional_frames:
            ref_t, ref_paths = _read_reference_frames(reference_dir)
            log.info("complementary filter towards %d frames of %s", len(ref_paths), reference_dir)
        next_ref = 0
        for k in range(vox.num_windows):
            stop = max(pos, int(vox.i1[k]))
            t_end = max(int(vox.t_end_us[k]), filt.t_us)
            # At each conventional frame before t_end, advance to the frame's time, then switch
            # the reference (exact: L_ref is constant between frames).
            while next_ref < len(ref_t) and ref_t[next_ref] <= t_end:
                t_ref = max(int(ref_t[next_ref]), filt.t_us)
                mid = min(max(pos, ef.index_at(t_ref + 1)), stop)
                filt.advance(ef.read(pos, mid), t_ref)
                pos = mid
                filt.set_reference(_log_frame(ref_paths[next_ref], (ef.height, ef.width)))
                next_ref += 1
            image = filt.advance(ef.read(pos, stop), t_end)
            pos = stop
            yield int(vox.t_end_us[k]), image.astype(np.float32)
    finally:
        ef.close()


def run_recon(
    voxel_path: str | Path,
    out_dir: str | Path,
    conf: ReconstructConfig,
    events_path: str | Path | None = None,
    reference_frames_dir: str | Path | None = None,
    num_threads: int | None = None,
) -> Path:
    """Reconstruct one frame per window of ``voxel_path`` into the folder ``out_dir``.

    Args:
        voxel_path: voxel file of :func:`evdense.events.voxel.make_voxels` (raw grids
            ``(windows, B, H, W)``, window times ``t_start_us``/``t_end_us``, event ranges ``i0``/``i1``).
        out_dir: frames folder to create (replaced atomically): ``000000.png, ...`` 8-bit grey
            and ``timestamps.txt`` with ``index t_seconds`` (window end times, seconds).
        conf: the method and its options.
        events_path: the canonical event file (required by the baselines).
        reference_frames_dir: conventional frames folder for the complementary filter
            (highpass with ``use_conventional_frames``).
        num_threads: torch intra-op threads (None: leave torch's setting).

    Returns:
        ``out_dir``.
    """
    out_dir = Path(out_dir)
    if num_threads is not None:
        torch.set_num_threads(max(1, int(num_threads)))
    vox = VoxelFile(voxel_path)
    try:
        if vox.num_windows == 0:
            raise ValueError(f"{vox.path}: no windows in the voxel file")
        if conf.is_baseline:
            if events_path is None:
                raise ValueError(
                    f"method {conf.method!r} reconstructs from events: give events_path"
                )
            frames = _baseline_frames(
                vox,
                conf,
                Path(events_path),
                Path(reference_frames_dir) if reference_frames_dir else None,
            )
        else:
            frames = _network_frames(vox, conf)
        rescale = conf.auto_hdr or conf.is_baseline
        rescaler = RobustRescaler(
            conf.hdr_min_percentile, conf.hdr_max_percentile, conf.hdr_window, conf.hdr_border
        )
        start = time.monotonic()
        with FrameWriter(out_dir) as writer:
            for t_us, img in progress(frames, total=vox.num_windows, desc=f"{conf.method} frames"):
                if rescale:
                    img = rescaler(img)
                img = unsharp_mask(img, conf.unsharp_sigma, conf.unsharp_amount)
                writer.write(img, t_us * 1e-6)
        elapsed = time.monotonic() - start
        log.info(
            "%s: %d frames in %.1f s (%.1f ms/frame incl. I/O) -> %s",
            conf.method, vox.num_windows, elapsed, 1e3 * elapsed / vox.num_windows, out_dir,
        )  # fmt: skip
    finally:
        vox.close()
    return out_dir
