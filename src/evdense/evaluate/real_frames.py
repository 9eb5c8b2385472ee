"""Reconstruction quality on real events against real APS frames (EVREAL-style, full reference).

A clip is a short real recording: its events (microseconds, pixels, polarity) and one or more APS
frames of the same sensor. Every method runs over the clip from an empty state on windows of a
fixed number of events; each APS frame is compared with the reconstruction of the window whose
end is nearest the frame's time (or the last window when the frame's time is unknown).

Comparison: both images are rescaled by their own 1st and 99th percentiles (so a gain, an offset
and the unknown absolute brightness of events do not count, as in EVREAL), then MSE and SSIM on
the central part of the frame. The reconstruction may be displaced from the frame by a few pixels
(the nearest window ends up to half a window from the frame's time, and the rotation clips do not
say when their frame was taken), so the reconstruction is compared at the integer shift within
``max_shift`` pixels that maximises its normalised cross-correlation with the frame; the same
search is made for every method, and the shift is reported.

Readers for the two real layouts in the anchors: the Event Camera Dataset folder (``events.txt``,
``images.txt``, ``calib.txt``: :func:`read_ecd_clip`) and the rotation chunks, whose frame is the
middle-left panel of a 3 x 2 picture (:func:`read_rotation_clip`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evdense.evaluate.images import image_metrics, normalize_intensity
from evdense.events.voxel import voxel_grid

Reconstructor = Callable[[np.ndarray], np.ndarray]
"""A stateful method: voxel grid ``(B, H, W)`` -> frame ``(H, W)``; a new one per clip."""


@dataclass
class RealClip:
    """Events and APS frames of one real clip."""

    name: str
    t: np.ndarray
    """(N,) int64 microseconds, sorted."""
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    """(N,) polarity in {-1, +1}."""
    width: int
    height: int
    frames: list[tuple[int | None, np.ndarray]]
    """(time in microseconds or None when unknown, grey image (H, W) float64 in [0, 1])."""


def _grey(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img, np.float64)
    if a.ndim == 3:
        a = a[..., :3].mean(-1)
    return a / 255.0


def _read_events(path: Path):
    from evdense.io.text import RpgTextRecording

    ts, xs, ys, ps = [], [], [], []
    with RpgTextRecording(path) as rec:
        for b in rec.iter_events():
            ts.append(b.t), xs.append(b.x), ys.append(b.y), ps.append(b.p)
        frames = [(f.t_us, f) for f in rec.iter_frames()]
    p = np.concatenate(ps)
    return (np.concatenate(ts).astype(np.int64), np.concatenate(xs).astype(np.int64),
            np.concatenate(ys).astype(np.int64), np.where(p > 0, 1.0, -1.0), frames)  # fmt: skip


ECD_SENSOR = (240, 180)
"""Width and height of the DAVIS240C, the sensor of every Event Camera Dataset sequence."""


def _check_on_sensor(path: Path, x: np.ndarray, y: np.ndarray) -> tuple[int, int]:
    w, h = ECD_SENSOR
    if len(x) and (x.min() < 0 or y.min() < 0 or x.max() >= w or y.max() >= h):
        raise ValueError(f"{path}: events off the {w} x {h} DAVIS240C sensor")
    return w, h


def read_ecd_clip(folder: str | Path) -> RealClip:
    """An Event Camera Dataset folder with ``events.txt`` and ``images.txt`` + ``images/``."""
    import imageio.v3 as iio

    folder = Path(folder)
    t, x, y, p, frames = _read_events(folder / "events.txt")
    w, h = _check_on_sensor(folder / "events.txt", x, y)
    out = []
    for t_us, f in frames:
        img = f.image if f.image is not None else iio.imread(f.source)
        out.append((int(t_us), _grey(img)))
    return RealClip(folder.name, t, x, y, p, w, h, out)


def read_rotation_clip(folder: str | Path) -> RealClip:
    """A rotation chunk of the anchors: ``events.txt`` and ``000000000.png``.

    The picture is a 3 x 2 panel of 240 x 180 images (an event visualisation, an event frame, the
    APS frame, and three reconstructions by other methods); the APS frame is the middle-left panel
    (the only one with the sensor's vignetting and read noise). Its time is not given.
    """
    import imageio.v3 as iio

    folder = Path(folder)
    t, x, y, p, _ = _read_events(folder / "events.txt")
    w, h = _check_on_sensor(folder / "events.txt", x, y)
    pic = iio.imread(folder / "000000000.png")
    if pic.shape[0] != 3 * h or pic.shape[1] != 2 * w:
        raise ValueError(f"{folder / '000000000.png'}: expected a 3 x 2 panel of {w} x {h} images")
    return RealClip(folder.name, t, x, y, p, w, h, [(None, _grey(pic[h : 2 * h, :w]))])


def read_anchor_clips(data: str | Path) -> list[RealClip]:
    """The real clips of the anchors' ``data`` folder in benchmark order: ``ecd_slider_depth``,
    then each folder of ``ecd_rotation`` in sorted order."""
    data = Path(data)
    if not data.is_dir():
        raise FileNotFoundError(f"{data}: anchors data folder not found")
    clips = [read_ecd_clip(data / "ecd_slider_depth")]
    rot = data / "ecd_rotation"
    return clips + [read_rotation_clip(d) for d in sorted(rot.iterdir()) if d.is_dir()]


def shifted_metrics(pred: np.ndarray, ref: np.ndarray, max_shift: int) -> dict[str, float]:
    """MSE and SSIM of ``pred`` against ``ref`` at the best integer shift (see module docstring).

    Both are compared on ``ref``'s central part (``max_shift`` pixels in from each side), each
    rescaled by its own 1st-99th percentiles there. Returns ``mse``, ``ssim``, ``dx``, ``dy``.
    """
    m = int(max_shift)
    h, w = ref.shape
    r = normalize_intensity(ref[m : h - m, m : w - m])
    rz = (r - r.mean()) / max(r.std(), 1e-12)
    best = (-np.inf, 0, 0)
    for dy in range(-m, m + 1):
        for dx in range(-m, m + 1):
            c = pred[m + dy : h - m + dy, m + dx : w - m + dx]
            cz = (c - c.mean()) / max(c.std(), 1e-12)
            score = float((cz * rz).mean())
            if score > best[0]:
                best = (score, dx, dy)
    _, dx, dy = best
    c = normalize_intensity(pred[m + dy : h - m + dy, m + dx : w - m + dx])
    s = image_metrics(c, r)
    return {"mse": s["mse"], "ssim": s["ssim"], "dx": dx, "dy": dy}


def reconstruct_clip(
    clip: RealClip, make: Callable[[], Reconstructor], events_per_window: int, bins: int = 5
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Run a fresh method from ``make()`` over ``clip`` in windows of ``events_per_window`` events
    (a last, shorter window is dropped): the time of each window's last event (us) and its frame."""
    rec = make()
    n = int(events_per_window)
    ends, frames = [], []
    for a in range(0, len(clip.t) - n + 1, n):
        sl = slice(a, a + n)
        v = voxel_grid(
            clip.t[sl], clip.x[sl], clip.y[sl], clip.p[sl], bins, clip.height, clip.width
        )
        frames.append(np.asarray(rec(v), np.float64))
        ends.append(int(clip.t[a + n - 1]))
    if not frames:
        raise ValueError(f"{clip.name}: fewer than {n} events ({len(clip.t)})")
    return np.array(ends, dtype=np.int64), frames


def evaluate_clip(
    clip: RealClip,
    make: Callable[[], Reconstructor],
    events_per_window: int,
    bins: int = 5,
    max_shift: int = 10,
) -> list[dict[str, float]]:
    """Run a fresh method from ``make()`` over ``clip`` and score it against each of its frames
    (:func:`reconstruct_clip`, then :func:`score_clip`). One row per frame."""
    ends, frames = reconstruct_clip(clip, make, events_per_window, bins)
    return score_clip(clip, ends, frames, max_shift)


def score_clip(
    clip: RealClip, ends: np.ndarray, frames: list[np.ndarray], max_shift: int = 10
) -> list[dict[str, float]]:
    """Score the reconstructions ``frames`` of windows ending at ``ends`` (as returned by
    :func:`reconstruct_clip`) against each frame of ``clip``. A frame with a time is compared with
    the window whose end is nearest, when that is within one window's span of the first or last
    window; a frame without one with the last window. One row per frame."""
    span = (ends[-1] - int(clip.t[0])) / len(ends)
    rows = []
    for k, (t_us, img) in enumerate(clip.frames):
        if t_us is None:
            j = len(frames) - 1
        else:
            if t_us < ends[0] - span / 2 or t_us > ends[-1] + span / 2:
                continue
            j = int(np.argmin(np.abs(ends - t_us)))
        s = shifted_metrics(frames[j], img, max_shift)
        dt = None if t_us is None else (int(ends[j]) - t_us) * 1e-3
        rows.append({"frame": k, "window": j, "dt_ms": dt, **s})
    return rows
