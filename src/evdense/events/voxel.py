"""Voxel grids of events (E2VID's input), fast on CPU and on torch devices, written one file per dataset.

Each event of a window adds its polarity to the two temporal bins nearest to its normalised time
``t* = (B - 1) (t - t0) / (t_last - t0)`` with weight ``max(0, 1 - |n - t*|)`` for bin ``n``, where
``t0``/``t_last`` are the first/last timestamps of the window (Rebecq et al., E2VID, 2019). When
``t_last == t0`` every event has ``t* = 0`` (E2VID takes the time span as 1 there).

Implementations, all equal up to float rounding:

- :func:`voxel_grid`: the one to use on CPU (numba kernel; numpy ``bincount`` when numba is absent).
- :func:`voxel_grid_torch`: torch ``index_add_``, on any device (CUDA for voxelising on the GPU).
- :func:`voxel_grid_reference`: the straightforward ``np.add.at`` form, for tests and benchmarks.

Files store RAW grids; :func:`normalize_voxel` applies E2VID/FireNet's input normalisation (non-zero
entries to mean 0, std 1) where a network wants it.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from evdense.events.container import EventFile, Events, compression_options
from evdense.events.windows import WindowConfig, read_windows, window_spec
from evdense.formats.files import Closing
from evdense.log import get_logger, progress

log = get_logger("events.voxel")

VOXELS_FORMAT = "evdense-voxels"
VOXELS_VERSION = 1

try:  # numba is optional: without it the numpy path is used (about 6x slower).
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is installed in the project environment
    HAVE_NUMBA = False


@dataclass(frozen=True)
class VoxelConfig:
    """How windows of events become voxel grids and how they are stored."""

    bins: int = 5
    """Temporal bins B of a voxel grid (the default in file names voxels_<spec>_b<B>.h5)."""
    dtype: str = "float32"
    """Stored value type, ``float32`` or ``float16`` (half the disk, about 3 significant digits)."""
    compression: str = "blosc-lz4"
    """HDF5 compression of the grids (blosc-lz4 fastest, zstd smaller, lzf/gzip readable without
    hdf5plugin, none)."""
    read_block_events: int = 1 << 22
    """Events read from the event file at a time (13 bytes each); bounds the memory of the stage."""
    hot_pixel_factor: float = 10.0
    """Hot-pixel filter: a pixel that fired, over the whole recording, more than this many times the
    second largest count of its 8 neighbours (at least 1) is masked (zero in every grid; listed in
    the voxel file's hot_pixels); 0 = off. A real sensor's hot pixels fire hundreds of times where
    their neighbours fire a few (66 of them in the DVXplorer sample), and the network renders each
    as a dot that spreads into a ring. The highpass and integrate baselines read the events
    themselves, unfiltered."""
    hot_pixel_min_ratio: float = 3.0
    """...and only if its count also exceeds this many times the mean count of the pixels that
    fired (so that a quiet recording's scattered events are not taken for hot pixels)."""

    def __post_init__(self) -> None:
        if self.bins < 1:
            raise ValueError(f"voxel bins must be >= 1, got {self.bins}")
        if self.dtype not in ("float32", "float16"):
            raise ValueError(f"voxel dtype must be float32 or float16, got {self.dtype!r}")
        compression_options(self.compression)  # raises ValueError on an unknown name
        if self.read_block_events < 1:
            raise ValueError("voxel read_block_events must be >= 1")
        if not (self.hot_pixel_factor >= 0 and self.hot_pixel_min_ratio >= 0):
            raise ValueError(
                "voxel hot_pixel_factor and hot_pixel_min_ratio must be >= 0, got "
                f"{self.hot_pixel_factor}, {self.hot_pixel_min_ratio}"
            )


# ---------------------------------------------------------------------------------------------
# Voxel grids of one window
# ---------------------------------------------------------------------------------------------


def _time_bounds(t: np.ndarray, t0: float | None, t1: float | None) -> tuple[float, float]:
    if len(t) == 0:
        return (0.0 if t0 is None else float(t0)), (0.0 if t1 is None else float(t1))
    return float(t[0] if t0 is None else t0), float(t[-1] if t1 is None else t1)


def voxel_grid_reference(
    t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, bins: int, height: int, width: int
) -> np.ndarray:
    """Voxel grid ``(bins, height, width)`` float32 by ``np.add.at``, written the straightforward way.

    This is the form of E2VID's public ``events_to_voxel_grid`` (float32 grid, two ``np.add.at``
    calls): slow, kept as the reference that the fast paths are tested and timed against.
    ``t`` in any unit, sorted (first/last entries are the window bounds); ``p`` in {-1, +1}.
    """
    grid = np.zeros((bins, height, width), np.float32).ravel()
    if len(t) == 0:
        return grid.reshape(bins, height, width)
    span = float(t[-1] - t[0]) or 1.0
    ts = (bins - 1) * (np.asarray(t, np.float64) - float(t[0])) / span
    tis = np.floor(ts).astype(np.int64)
    dts = ts - tis
    pol = np.asarray(p, np.float64)
    idx = np.asarray(x, np.int64) + np.asarray(y, np.int64) * width + tis * width * height
    valid = (tis >= 0) & (tis < bins)
    np.add.at(grid, idx[valid], (pol * (1.0 - dts))[valid])
    valid = (tis + 1 >= 0) & (tis + 1 < bins)
    np.add.at(grid, idx[valid] + width * height, (pol * dts)[valid])
    return grid.reshape(bins, height, width)


if HAVE_NUMBA:

    @numba.njit(cache=True, nogil=True)
    def _voxel_kernel(t, x, y, p, t0, t1, nbins, height, width, out):  # pragma: no cover - jitted
        """Accumulate into flat ``out`` (nbins*height*width); returns the count of events off the sensor.

        Events are split into runs by ``floor(t*)`` with a bisection (they are sorted in time), so
        the inner loop touches two planes only; an event whose t* falls outside its run (unsorted
        input, float edge cases) takes the general formula, so any order gives the exact result.
        """
        span = t1 - t0
        sc = (nbins - 1) / span if span > 0 else 0.0
        hw = height * width
        n = t.shape[0]
        bad = 0
        i = 0
        for k in range(nbins):
            if k == nbins - 1:
                j = n
            else:
                lo, hi = i, n
                while lo < hi:
                    m = (lo + hi) // 2
                    if (t[m] - t0) * sc >= k + 1:
                        hi = m
                    else:
                        lo = m + 1
                j = lo
            for e in range(i, j):
                xe = np.int64(x[e])
                ye = np.int64(y[e])
                if xe < 0 or xe >= width or ye < 0 or ye >= height:
                    bad += 1
                    continue
                ts = (t[e] - t0) * sc
                f = ts - k
                pix = ye * width + xe
                pv = np.float64(p[e])
                if f >= 0.0 and f < 1.0:
                    w = pv * f
                    out[k * hw + pix] += np.float32(pv - w)
                    if k + 1 < nbins:
                        out[(k + 1) * hw + pix] += np.float32(w)
                else:
                    tl = np.int64(np.floor(ts))
                    for b in range(tl, tl + 2):
                        if b >= 0 and b < nbins:
                            wb = 1.0 - abs(b - ts)
                            if wb > 0.0:
                                out[b * hw + pix] += np.float32(pv * wb)
            i = j
        return bad


def _voxel_numpy(t, x, y, p, t0, t1, bins, height, width, out_flat) -> None:
    """bincount form: two weighted histograms over flattened (bin, y, x) indices."""
    span = t1 - t0
    sc = (bins - 1) / span if span > 0 else 0.0
    ts = (np.asarray(t, np.float64) - t0) * sc
    tl = np.floor(ts)
    f = ts - tl
    tl = tl.astype(np.intp)
    hw = height * width
    pix = np.asarray(y, np.intp) * width + np.asarray(x, np.intp)
    pol = np.asarray(p, np.float64)
    for b, w in ((tl, pol * (1.0 - f)), (tl + 1, pol * f)):
        ok = (b >= 0) & (b < bins)
        if not ok.all():
            b, w, px = b[ok], w[ok], pix[ok]
        else:
            px = pix
        out_flat += np.bincount(b * hw + px, w, minlength=bins * hw)[: bins * hw].astype(np.float32)


def voxel_grid(
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    bins: int,
    height: int,
    width: int,
    t0: float | None = None,
    t1: float | None = None,
    out: np.ndarray | None = None,
    backend: str = "auto",
) -> np.ndarray:
    """Voxel grid ``(bins, height, width)`` float32 of one window of events.

    ``t``: timestamps (any unit, microseconds in evdense), sorted for full speed; ``x``, ``y``:
    pixel column and row; ``p``: polarity in {-1, +1}. ``t0``/``t1``: the window's first and last
    timestamps (default ``t[0]``/``t[-1]``); give them to build one window from several pieces,
    adding into ``out`` (a C-contiguous float32 ``(bins, height, width)`` array, accumulated into).
    ``backend``: ``auto`` (numba when installed), ``numba`` or ``numpy``.
    Raises ``ValueError`` when an event lies off the ``width`` x ``height`` sensor.
    """
    if out is None:
        out = np.zeros((bins, height, width), np.float32)
    elif (
        out.shape != (bins, height, width) or out.dtype != np.float32 or not out.flags.c_contiguous
    ):
        raise ValueError(
            f"out must be C-contiguous float32 {(bins, height, width)}, got {out.shape} {out.dtype}"
        )
    n = len(t)
    if not (len(x) == len(y) == len(p) == n):
        raise ValueError(
            f"event arrays differ in length: t {n}, x {len(x)}, y {len(y)}, p {len(p)}"
        )
    if n == 0:
        return out
    lo, hi = _time_bounds(t, t0, t1)
    if backend == "auto":
        backend = "numba" if HAVE_NUMBA else "numpy"
    flat = out.reshape(-1)
    if backend == "numba":
        if not HAVE_NUMBA:
            raise ValueError("voxel backend 'numba' asked for but numba is not installed")
        t = np.asarray(t)
        if t.dtype.kind in "iu":
            t = t.astype(np.int64, copy=False)
        else:
            t = t.astype(np.float64, copy=False)
        bad = _voxel_kernel(t, x, y, p, lo, hi, bins, height, width, flat)
        if bad:
            raise ValueError(f"{bad} events lie off the {width}x{height} sensor")
    elif backend == "numpy":
        xa, ya = np.asarray(x), np.asarray(y)
        if xa.min() < 0 or ya.min() < 0 or xa.max() >= width or ya.max() >= height:
            raise ValueError(f"events lie off the {width}x{height} sensor")
        _voxel_numpy(t, xa, ya, p, lo, hi, bins, height, width, flat)
    else:
        raise ValueError(f"unknown voxel backend {backend!r} (auto, numba, numpy)")
    return out


def events_voxel_grid(events: Events, bins: int, height: int, width: int) -> np.ndarray:
    """Voxel grid ``(bins, height, width)`` float32 of a batch of :class:`Events` (one window)."""
    return voxel_grid(events.t, events.x, events.y, events.p, bins, height, width)


def voxel_grid_torch(
    t: Any,
    x: Any,
    y: Any,
    p: Any,
    bins: int,
    height: int,
    width: int,
    device: Any = None,
    t0: float | None = None,
    t1: float | None = None,
) -> Any:
    """Voxel grid ``(bins, height, width)`` as a float32 ``torch.Tensor`` on ``device``.

    Inputs are numpy arrays or tensors (moved to ``device``; default: the device of ``t`` when a
    tensor, else CPU). Same definition as :func:`voxel_grid`; uses ``index_add_``, so it runs on
    CUDA. Times are taken relative to ``t0`` before conversion to float32, so microsecond int64
    timestamps keep their precision.
    """
    import torch

    if device is None:
        device = t.device if isinstance(t, torch.Tensor) else "cpu"

    def _tensor(a: Any) -> torch.Tensor:
        a = (
            torch.as_tensor(a)
            if isinstance(a, torch.Tensor)
            else torch.from_numpy(np.ascontiguousarray(a))
        )
        return a.to(device)

    out = torch.zeros(bins * height * width, dtype=torch.float32, device=device)
    tt = _tensor(t)
    if tt.numel() == 0:
        return out.view(bins, height, width)
    xt = _tensor(x).long()
    yt = _tensor(y).long()
    if bool(((xt < 0) | (xt >= width) | (yt < 0) | (yt >= height)).any()):
        raise ValueError(f"events lie off the {width}x{height} sensor")
    lo = float(tt[0]) if t0 is None else float(t0)
    hi = float(tt[-1]) if t1 is None else float(t1)
    span = hi - lo
    sc = (bins - 1) / span if span > 0 else 0.0
    # Subtract t0 before leaving int64/float64 so that microsecond timestamps keep their precision;
    # float32 after that is exact to 1 us over 16 s windows.
    if not tt.is_floating_point() and float(lo).is_integer():
        ts = (tt - int(lo)).float() * sc
    else:
        ts = ((tt.double() - lo) * sc).float()
    tl = torch.floor(ts)
    f = ts - tl
    tl = tl.long()
    pol = _tensor(p).float()
    pix = yt * width + xt
    hw = height * width
    for b, w in ((tl, pol * (1.0 - f)), (tl + 1, pol * f)):
        # zero weights instead of boolean indexing: no compaction, no host sync on CUDA
        ok = (b >= 0) & (b < bins)
        idx = b.clamp(0, bins - 1) * hw + pix
        out.index_add_(0, idx, torch.where(ok, w, torch.zeros((), dtype=w.dtype, device=w.device)))
    return out.view(bins, height, width)


def normalize_voxel(grid: Any) -> Any:
    """E2VID/FireNet input normalisation: the non-zero entries of each grid to mean 0, std 1.

    ``grid``: ``(B, H, W)`` or ``(N, B, H, W)`` numpy array or torch tensor; returns a new float32
    array/tensor of the same kind and shape, zeros staying zero. The std is the population std of
    the non-zero entries (as E2VID); a grid whose non-zero entries are all equal is only centred.
    """
    try:
        import torch

        is_torch = isinstance(grid, torch.Tensor)
    except ImportError:  # pragma: no cover
        is_torch = False
    if grid.ndim == 4:
        if is_torch:
            return torch.stack([normalize_voxel(g) for g in grid])
        return np.stack([normalize_voxel(g) for g in grid])
    if grid.ndim != 3:
        raise ValueError(
            f"voxel grid must be (B, H, W) or (N, B, H, W), got shape {tuple(grid.shape)}"
        )
    g = grid.float() if is_torch else np.asarray(grid, np.float32)
    mask = g != 0
    nnz = int(mask.sum())
    if nnz == 0:
        return g.clone() if is_torch else g.copy()
    mean = float(g.sum(dtype=torch.float64) if is_torch else g.sum(dtype=np.float64)) / nnz
    sq = float((g.double() ** 2).sum()) if is_torch else float((g.astype(np.float64) ** 2).sum())
    var = max(sq / nnz - mean * mean, 0.0)
    std = var**0.5
    scale = 1.0 / std if std > 1e-12 else 1.0
    if is_torch:
        return torch.where(mask, (g - mean) * scale, torch.zeros_like(g))
    return np.where(mask, (g - mean) * scale, 0.0).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# All windows of a recording -> one HDF5 file, in bounded memory
# ---------------------------------------------------------------------------------------------


class _EventBuffer:
    """A block of consecutive events, reloaded as requested index ranges move forward."""

    def __init__(self, ef: EventFile, block: int) -> None:
        self.ef, self.block = ef, block
        self.start, self.ev = 0, Events.empty()

    def get(self, i0: int, i1: int) -> Events:
        """Events ``i0:i1`` (``i1 - i0 <= block``) as views into the block."""
        if not (self.start <= i0 and i1 <= self.start + len(self.ev)):
            self.start = i0
            self.ev = self.ef.read(i0, max(i1, i0 + self.block))
        return self.ev[i0 - self.start : i1 - self.start]


def events_per_pixel(ef: EventFile, block: int = 1 << 22) -> np.ndarray:
    """Number of events of every pixel over the whole file, ``(height, width)`` int64."""
    n = ef.height * ef.width
    counts = np.zeros(n, np.int64)
    for ev in ef.iter_chunks(block):
        counts += np.bincount(ev.y.astype(np.int64) * ef.width + ev.x.astype(np.int64), minlength=n)
    return counts.reshape(ef.height, ef.width)


def find_hot_pixels(counts: np.ndarray, factor: float, min_ratio: float) -> np.ndarray:
    """Flat indices (``y * width + x``, sorted) of the hot pixels of a count image ``(H, W)``.

    Hot: more than ``factor`` times the second largest count of its 8 neighbours (at least 1),
    and more than ``min_ratio`` times the mean count of the pixels with any event. Moving edges
    and texture fire in runs of neighbouring pixels (a one-pixel line still has two neighbours
    on it), so real signal keeps its neighbours' order of magnitude; a hot pixel, or a pair of
    them, stands alone. ``factor`` 0 finds none.
    """
    counts = np.asarray(counts, np.int64)
    if factor <= 0 or not counts.any():
        return np.zeros(0, np.int64)
    h, w = counts.shape
    padded = np.pad(counts, 1, mode="edge")
    around = np.stack(
        [
            padded[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
            for dy in (-1, 0, 1)
            for dx in (-1, 0, 1)
            if dy or dx
        ]
    )
    second = np.partition(around, 6, axis=0)[6]  # second largest of the 8 neighbours
    mean_active = counts[counts > 0].mean()
    hot = (counts > factor * np.maximum(second, 1)) & (counts > min_ratio * mean_active)
    return np.flatnonzero(hot)


def _window_voxels(
    buf: _EventBuffer, i0: int, i1: int, bins: int, height: int, width: int, out: np.ndarray
) -> None:
    """Voxel grid of events ``[i0, i1)`` into ``out``, in pieces of at most one read block."""
    if i1 <= i0:
        return
    if i1 - i0 <= buf.block:
        ev = buf.get(i0, i1)
        voxel_grid(ev.t, ev.x, ev.y, ev.p, bins, height, width, out=out)
        return
    # A window larger than a read block: its bounds first, then the pieces.
    t0 = int(buf.ef.read_t(i0, i0 + 1)[0])
    t1 = int(buf.ef.read_t(i1 - 1, i1)[0])
    for a in range(i0, i1, buf.block):
        ev = buf.get(a, min(a + buf.block, i1))
        voxel_grid(ev.t, ev.x, ev.y, ev.p, bins, height, width, t0=t0, t1=t1, out=out)


# Over 80 lines on purpose: one pass over the windows in batches (read each window's events,
# bin, write the batch) with progress, inside one HDF5 file written whole or not at all; the
# binning itself is voxel_grid().
def make_voxels(
    events_path: str | Path, windows_path: str | Path, out_path: str | Path, conf: VoxelConfig
) -> Path:
    """Stage: voxel grids of all windows of a recording, written to one HDF5 file.

    Layout of ``out_path``: ``voxels`` ``(num_windows, bins, height, width)`` RAW grids (``conf.dtype``,
    one chunk per window, compressed); ``t_start_us``, ``t_end_us``, ``count``, ``i0``, ``i1`` copied
    from the windows table; ``hot_pixels`` ``(K, 2)`` int32 ``x, y`` of the pixels masked by the
    hot-pixel filter (:func:`find_hot_pixels`; zero in every grid); attrs ``format``,
    ``version``, ``width``, ``height``, ``bins``, ``spec``, ``normalized`` (False), ``time_unit``
    ("us"), ``source``, ``windows``. Memory stays bounded by ``conf.read_block_events`` and a few
    grids, however long the recording. Written under a temporary name and renamed when complete.
    """
    out_path = Path(out_path)
    windows, wattrs = read_windows(windows_path)
    bins = conf.bins
    with EventFile(events_path) as ef:
        if len(windows) and int(windows.i1.max()) > ef.num_events:
            raise ValueError(
                f"{windows_path}: windows reach event {int(windows.i1.max())} but {events_path} holds "
                f"{ef.num_events}; the windows were made from another event file"
            )
        h, w = ef.height, ef.width
        nw = len(windows)
        hot = np.zeros(0, np.int64)
        if conf.hot_pixel_factor > 0:
            counts = events_per_pixel(ef, conf.read_block_events)
            hot = find_hot_pixels(counts, conf.hot_pixel_factor, conf.hot_pixel_min_ratio)
            log.info(
                "%s: %d hot pixels masked (%d of %d events)",
                events_path, len(hot), int(counts.ravel()[hot].sum()), ef.num_events,
            )  # fmt: skip
        grid_bytes = bins * h * w * 4
        per_write = int(max(1, min(64, (32 << 20) // grid_bytes)))
        out_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = out_path.with_name(out_path.name + ".partial")
        comp = compression_options(conf.compression)
        try:
            with h5py.File(tmp, "w") as f:
                ds = f.create_dataset(
                    "voxels",
                    shape=(nw, bins, h, w),
                    dtype=conf.dtype,
                    chunks=(1, bins, h, w) if nw else None,
                    **(comp if nw else {}),
                )
                for k in ("i0", "i1", "t_start_us", "t_end_us"):
                    f.create_dataset(k, data=getattr(windows, k))
                f.create_dataset("count", data=windows.count)
                f.create_dataset(
                    "hot_pixels", data=np.stack([hot % w, hot // w], 1).astype(np.int32)
                )  # (K, 2) x, y of the masked pixels
                buf = _EventBuffer(ef, conf.read_block_events)
                grids = np.zeros((per_write, bins, h, w), np.float32)
                starts = range(0, nw, per_write)
                for s in progress(starts, len(starts), desc=f"voxels {out_path.name}", logger=log):
                    e = min(s + per_write, nw)
                    grids[: e - s] = 0.0
                    for k in range(s, e):
                        _window_voxels(
                            buf, int(windows.i0[k]), int(windows.i1[k]), bins, h, w, grids[k - s]
                        )
                    if len(hot):
                        grids[: e - s].reshape(e - s, bins, h * w)[:, :, hot] = 0.0
                    ds[s:e] = grids[: e - s]
                a = f.attrs
                a["format"] = VOXELS_FORMAT
                a["version"] = VOXELS_VERSION
                a["width"] = w
                a["height"] = h
                a["bins"] = bins
                a["num_windows"] = nw
                a["spec"] = wattrs.get("spec", "")
                a["normalized"] = False
                a["time_normalisation"] = "first and last event of each window (E2VID)"
                a["time_unit"] = "us"
                a["dtype"] = conf.dtype
                a["config"] = str(asdict(conf))
                a["source"] = str(events_path)
                a["windows"] = str(windows_path)
            os.replace(tmp, out_path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    log.info("%s: %d voxel grids %dx%dx%d written", out_path, nw, bins, h, w)
    return out_path


def voxel_file_name(window: WindowConfig | Mapping[str, Any], bins: int) -> str:
    """File name of the voxel grids of these windows: ``voxels_<spec>_b<bins>.h5`` (under events/)."""
    return f"voxels_{window_spec(window)}_b{int(bins)}.h5"


class VoxelFile(Closing):
    """Read a voxel file written by :func:`make_voxels`, window by window or in blocks.

    Attributes: ``num_windows``, ``bins``, ``height``, ``width``, ``spec``, ``normalized`` (False
    for files of :func:`make_voxels`), int64 arrays ``t_start_us``, ``t_end_us``, ``count``,
    ``i0``, ``i1`` (microseconds / event indices, one entry per window), and ``hot_pixels``
    ``(K, 2)`` (``x, y`` of the pixels the hot-pixel filter masked).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such voxel file")
        self._f = h5py.File(self.path, "r")
        a = self._f.attrs
        if a.get("format") != VOXELS_FORMAT:
            self._f.close()
            raise ValueError(f"{self.path}: not an evdense voxel file (format {a.get('format')!r})")
        self.bins = int(a["bins"])
        self.height = int(a["height"])
        self.width = int(a["width"])
        self.num_windows = int(a["num_windows"])
        self.spec = str(a["spec"])
        self.normalized = bool(a["normalized"])
        self._ds = self._f["voxels"]
        for k in ("t_start_us", "t_end_us", "count", "i0", "i1"):
            setattr(self, k, self._f[k][()])
        # x, y of the masked hot pixels (K, 2); files made before the filter have none
        hp = self._f.get("hot_pixels")
        self.hot_pixels = hp[()] if hp is not None else np.zeros((0, 2), np.int32)

    def close(self) -> None:
        self._f.close()

    def __len__(self) -> int:
        return self.num_windows

    def read(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Grids ``start:stop`` as float32 ``(n, bins, height, width)``."""
        stop = self.num_windows if stop is None else min(stop, self.num_windows)
        return self._ds[start:stop].astype(np.float32, copy=False)

    def __getitem__(self, k: int) -> np.ndarray:
        """Grid of window ``k`` as float32 ``(bins, height, width)``."""
        if not -self.num_windows <= k < self.num_windows:
            raise IndexError(f"window {k} out of range (0..{self.num_windows - 1})")
        return self._ds[k].astype(np.float32, copy=False)

    def __iter__(self) -> Iterator[np.ndarray]:
        """All grids in order, float32 ``(bins, height, width)``, read a few at a time."""
        step = 16
        for s in range(0, self.num_windows, step):
            yield from self.read(s, s + step)
