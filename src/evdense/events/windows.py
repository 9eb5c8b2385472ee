"""Windows of events: fixed count, fixed duration, or fixed count capped by a duration.

A window is an index range ``[i0, i1)`` of the canonical event file with its start and end time.
All windows of a recording are one table (HDF5, ``windows_<spec>.h5``), computed in one streaming
pass over the timestamps, so memory does not grow with the recording (only with the table).

Modes (see :class:`WindowConfig`):

- ``events``: ``num_events`` events per window (E2VID's default); the last window holds the rest.
- ``time``: windows ``[t, t + duration)`` starting at the first event; empty windows are kept.
- ``events_capped``: ``num_events`` events, but a window ends early when it would last longer
  than ``max_duration_ms`` (so slow scenes still get frames).

Without overlap the windows partition the stream: every event is in exactly one window. With
``overlap = o`` the start of each window moves on by ``(1 - o)`` of a window (events, or time for
``time`` mode), so each event is in about ``1 / (1 - o)`` windows; the last window always ends at
the last event.

Window times (``t_start_us``, ``t_end_us``, microseconds): for the event modes, the timestamps of
the first and last event of the window; for ``time`` mode, the nominal bounds ``[t, t + duration)``.
``t_end_us`` is the timestamp given to the frame reconstructed from the window.

The window spec string names the parameters in file names: ``n25000``, ``dt50ms``,
``n25000-max100ms``, and ``-ov0.5`` appended when there is overlap.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from evdense.config import section_from_dict
from evdense.events.container import EventFile
from evdense.log import get_logger

log = get_logger("events.windows")

WINDOWS_FORMAT = "evdense-windows"
WINDOWS_VERSION = 1

MODES = ("events", "time", "events_capped")

# Numbers as window_spec writes them (no leading or trailing zeros), so that the regex matches
# canonical specs only and two spellings of one config cannot name two files.
_NUM = r"(?:0|[1-9]\d*)(?:\.\d*[1-9])?"
#: Regular expression of a window spec (Snakemake wildcard constraint for ``{win}``).
WINDOW_SPEC_REGEX = rf"(?:n[1-9]\d*(?:-max{_NUM}ms)?|dt{_NUM}ms)(?:-ov0\.\d*[1-9])?"
_SPEC_RE = re.compile(
    rf"^(?:n(?P<n>\d+)(?:-max(?P<max>{_NUM})ms)?|dt(?P<dt>{_NUM})ms)(?:-ov(?P<ov>0\.\d+))?$"
)

# Timestamps are read in blocks of this many events (8 bytes each): bounds memory.
_READ_BLOCK = 1 << 22


@dataclass(frozen=True)
class WindowConfig:
    """How a stream of events is cut into windows (one reconstructed frame per window)."""

    mode: str = "events"
    """events = a fixed number of events per window (E2VID's default); time = a fixed duration;
    events_capped = a fixed number of events, ended early at max_duration_ms."""
    num_events: int = 25000
    """Events per window in the ``events`` modes (25000 is about 0.3 events per pixel at 346x260)."""
    duration_ms: float = 50.0
    """Window duration in milliseconds in ``time`` mode."""
    max_duration_ms: float = 100.0
    """Longest window in milliseconds in ``events_capped`` mode."""
    overlap: float = 0.0
    """Fraction of a window shared with the next one; 0 partitions the stream (each event in one
    window)."""

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"window mode must be one of {MODES}, got {self.mode!r}")
        if self.num_events < 1:
            raise ValueError(f"window num_events must be >= 1, got {self.num_events}")
        if not self.duration_ms > 0 or not self.max_duration_ms > 0:
            raise ValueError("window durations must be > 0 ms")
        if not 0.0 <= self.overlap < 1.0:
            raise ValueError(f"window overlap must be in [0, 1), got {self.overlap}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> WindowConfig:
        """Build from a config mapping (``config["events"]["window"]``); unknown keys are an error."""
        return section_from_dict(cls, d, "events.window")


def _fmt(x: float) -> str:
    """Shortest positional form of a number: 50.0 -> '50', 0.5 -> '0.5' (never an exponent)."""
    return np.format_float_positional(float(x), trim="-")


def window_spec(conf: WindowConfig | Mapping[str, Any]) -> str:
    """The spec string naming ``conf`` in file names, e.g. ``n25000``, ``dt50ms``, ``n25000-max100ms-ov0.5``."""
    if not isinstance(conf, WindowConfig):
        conf = WindowConfig.from_dict(conf)
    if conf.mode == "events":
        s = f"n{conf.num_events}"
    elif conf.mode == "events_capped":
        s = f"n{conf.num_events}-max{_fmt(conf.max_duration_ms)}ms"
    else:
        s = f"dt{_fmt(conf.duration_ms)}ms"
    if conf.overlap > 0:
        s += f"-ov{_fmt(conf.overlap)}"
    return s


def windows_file_name(conf: WindowConfig | Mapping[str, Any]) -> str:
    """File name of the windows table of ``conf``: ``windows_<spec>.h5`` (under events/)."""
    return f"windows_{window_spec(conf)}.h5"


def parse_window_spec(spec: str) -> WindowConfig:
    """Inverse of :func:`window_spec`; raises ``ValueError`` for a malformed or non-canonical spec."""
    m = _SPEC_RE.match(spec)
    if m is None:
        raise ValueError(
            f"bad window spec {spec!r}: expected n<N>, dt<ms>ms or n<N>-max<ms>ms, optionally -ov<0.x>"
        )
    ov = float(m["ov"]) if m["ov"] else 0.0
    if m["dt"] is not None:
        conf = WindowConfig(mode="time", duration_ms=float(m["dt"]), overlap=ov)
    elif m["max"] is not None:
        conf = WindowConfig(
            mode="events_capped",
            num_events=int(m["n"]),
            max_duration_ms=float(m["max"]),
            overlap=ov,
        )
    else:
        conf = WindowConfig(mode="events", num_events=int(m["n"]), overlap=ov)
    canonical = window_spec(conf)
    if canonical != spec:
        # Two names for one set of windows would make two files: accept only the canonical one.
        raise ValueError(f"window spec {spec!r} is not canonical; write it as {canonical!r}")
    return conf


@dataclass
class Windows:
    """A table of windows: aligned int64 arrays of length ``num_windows``.

    ``i0``, ``i1``: event index range ``[i0, i1)``; ``count = i1 - i0``; ``t_start_us``,
    ``t_end_us``: window times in microseconds (see the module docstring).
    """

    i0: np.ndarray
    i1: np.ndarray
    t_start_us: np.ndarray
    t_end_us: np.ndarray

    def __post_init__(self) -> None:
        for k in ("i0", "i1", "t_start_us", "t_end_us"):
            setattr(self, k, np.asarray(getattr(self, k), dtype=np.int64))

    @property
    def count(self) -> np.ndarray:
        """Events per window, ``(num_windows,)``."""
        return self.i1 - self.i0

    def __len__(self) -> int:
        return len(self.i0)


def _gather(ef: EventFile, idx: np.ndarray) -> np.ndarray:
    """``t[idx]`` for sorted indices ``idx``, reading the timestamps block by block."""
    block = _READ_BLOCK
    out = np.empty(len(idx), dtype=np.int64)
    if len(idx) == 0:
        return out
    j = 0
    while j < len(idx):
        s = int(idx[j])
        e = min(s + block, ef.num_events)
        k = j + int(np.searchsorted(idx[j:], e, side="left"))
        t = ef.read_t(s, e)
        out[j:k] = t[idx[j:k] - s]
        j = k
    return out


def _search_times(ef: EventFile, times_us: np.ndarray) -> np.ndarray:
    """For sorted ``times_us``: index of the first event with ``t >= time`` (as ``EventFile.index_at``).

    One sequential pass over the timestamps; many times cost no more than one read of the stream.
    """
    block = _READ_BLOCK
    out = np.full(len(times_us), ef.num_events, dtype=np.int64)
    j = 0
    for s in range(0, ef.num_events, block):
        if j >= len(times_us):
            break
        t = ef.read_t(s, s + block)
        # times at or before this block's last timestamp have their answer in this block
        k = j + int(np.searchsorted(times_us[j:], t[-1], side="right"))
        out[j:k] = s + np.searchsorted(t, times_us[j:k], side="left")
        j = k
    return out


def _event_windows(n: int, num: int, overlap: float) -> tuple[np.ndarray, np.ndarray]:
    stride = max(1, int(round(num * (1.0 - overlap))))
    # last start: the first window that reaches the end of the stream
    k_last = max(0, -(-(n - num) // stride)) if n > num else 0
    i0 = np.arange(k_last + 1, dtype=np.int64) * stride
    i1 = np.minimum(i0 + num, n)
    return i0, i1


def _capped_windows(
    ef: EventFile, num: int, max_us: int, overlap: float
) -> tuple[np.ndarray, np.ndarray]:
    n = ef.num_events
    block = max(_READ_BLOCK, num + 1)
    starts: list[int] = []
    ends: list[int] = []
    bs, t = 0, ef.read_t(0, block)
    i0 = 0
    while True:
        if i0 + num + 1 > bs + len(t) and bs + len(t) < n:
            bs, t = i0, ef.read_t(i0, i0 + block)
        lo = i0 - bs
        hi = min(lo + num, len(t))
        # first event at or after start + max duration, searched among the next num events
        cut = lo + int(np.searchsorted(t[lo:hi], t[lo] + max_us, side="left"))
        i1 = bs + max(cut, lo + 1)
        starts.append(i0)
        ends.append(i1)
        if i1 >= n:
            break
        step = max(1, int(round((i1 - i0) * (1.0 - overlap))))
        i0 += step
    return np.asarray(starts, dtype=np.int64), np.asarray(ends, dtype=np.int64)


def compute_windows(events: EventFile | str | Path, conf: WindowConfig) -> Windows:
    """Cut the recording into windows in one streaming pass over its timestamps.

    ``events``: an open :class:`EventFile` or the path of a canonical event file.
    Raises ``ValueError`` when the file holds no events.
    """
    if not isinstance(events, EventFile):
        with EventFile(events) as ef:
            return compute_windows(ef, conf)
    ef = events
    n = ef.num_events
    if n == 0:
        raise ValueError(f"{ef.path}: the event file holds no events; cannot make windows")
    if conf.mode == "time":
        dur = max(1, int(round(conf.duration_ms * 1000.0)))
        stride = dur * (1.0 - conf.overlap)
        span = ef.t_end_us - ef.t_start_us
        # windows until the first one that reaches past the last event
        k_max = int(np.ceil(max(0, span - dur + 1) / stride)) + 1
        ts = ef.t_start_us + np.round(np.arange(k_max + 1) * stride).astype(np.int64)
        ts = ts[: int(np.searchsorted(ts + dur, ef.t_end_us, side="right")) + 1]
        te = ts + dur
        return Windows(_search_times(ef, ts), _search_times(ef, te), ts, te)
    if conf.mode == "events":
        i0, i1 = _event_windows(n, conf.num_events, conf.overlap)
    else:
        max_us = max(1, int(round(conf.max_duration_ms * 1000.0)))
        i0, i1 = _capped_windows(ef, conf.num_events, max_us, conf.overlap)
    # i0 and i1 - 1 are each non-decreasing: gather their timestamps in order
    return Windows(i0, i1, _gather(ef, i0), _gather(ef, i1 - 1))


def write_windows(
    path: str | Path, windows: Windows, attrs: Mapping[str, Any] | None = None
) -> Path:
    """Write a windows table (HDF5) under a temporary name, then rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    try:
        with h5py.File(tmp, "w") as f:
            for k in ("i0", "i1", "t_start_us", "t_end_us"):
                f.create_dataset(k, data=getattr(windows, k))
            f.create_dataset("count", data=windows.count)
            f.attrs["format"] = WINDOWS_FORMAT
            f.attrs["version"] = WINDOWS_VERSION
            f.attrs["time_unit"] = "us"
            f.attrs["num_windows"] = len(windows)
            for k, v in (attrs or {}).items():
                f.attrs[k] = v
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def read_windows(path: str | Path) -> tuple[Windows, dict[str, Any]]:
    """Read a windows table: the :class:`Windows` and the file attributes."""
    path = Path(path)
    with h5py.File(path, "r") as f:
        if f.attrs.get("format") != WINDOWS_FORMAT:
            raise ValueError(
                f"{path}: not an evdense windows file (format {f.attrs.get('format')!r})"
            )
        w = Windows(f["i0"][()], f["i1"][()], f["t_start_us"][()], f["t_end_us"][()])
        attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
    return w, attrs


def make_windows(events_path: str | Path, out_path: str | Path, conf: WindowConfig) -> Path:
    """Stage: cut ``events_path`` (canonical event file) into windows and write ``out_path``."""
    with EventFile(events_path) as ef:
        w = compute_windows(ef, conf)
        attrs = {
            "spec": window_spec(conf),
            "config": str(asdict(conf)),
            "source": str(events_path),
            "width": ef.width,
            "height": ef.height,
            "num_events": ef.num_events,
        }
    c = w.count
    log.info(
        "%s: %d windows (%s), events per window min %d / median %d / max %d",
        events_path,
        len(w),
        attrs["spec"],
        c.min(),
        int(np.median(c)),
        c.max(),
    )
    return write_windows(out_path, w, attrs)
