"""The canonical event file: one HDF5 file per recording, read in bounded memory.

Layout (format ``evdense-events``, version 2)::

    /events/t     int64   timestamps in microseconds, non-decreasing
    /events/x     uint16  column, 0 <= x < width
    /events/y     uint16  row, 0 <= y < height
    /events/p     int8    polarity, -1 or +1
    /t_index_key  int64   sorted time buckets k that hold events (bucket k: t in
                          [t_offset + k * step, t_offset + (k + 1) * step), step = index_step_us)
    /t_index      int64   t_index[j] = index of the first event of bucket t_index_key[j]
    attrs: format, version, width, height, time_unit ("us"), num_events, t_start_us, t_end_us,
           t_offset_us, index_step_us, provenance (JSON string), and any extra attributes given

The time index is sparse: one entry per millisecond that holds events, so its size follows the
number of events, never the time span (three events an hour apart take three entries). Version 1
files (a dense ``t_index`` of one entry per millisecond, no ``t_index_key``) are still read.

Reading checks what the pipeline relies on, chunk by chunk: timestamps non-decreasing,
coordinates on the sensor, polarity -1 or +1 (:class:`~evdense.errors.InputError` naming the file
and the event otherwise), so a corrupted file stops a run instead of flowing through it.

Datasets are chunked and compressed (Blosc LZ4 with byte shuffle by default, through hdf5plugin:
about 4 bytes per event, read at over 100 M events/s; other HDF5 readers need ``import hdf5plugin``
or the Blosc filter plugin), so any time or index range can be read without reading the rest. A file is written under a temporary name and renamed when
complete, so a file with the final name is always whole.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import hdf5plugin
import numpy as np

from evdense.errors import InputError
from evdense.formats.files import Closing, CompleteOrAbsent

FORMAT_NAME = "evdense-events"
FORMAT_VERSION = 2
CHUNK_EVENTS = 1 << 18
INDEX_STEP_US = 1000

_DTYPES = {"t": np.int64, "x": np.uint16, "y": np.uint16, "p": np.int8}
MAX_SENSOR_SIDE = 65535
"""Largest sensor side in pixels (coordinates are stored as uint16)."""


def compression_options(name: str | None) -> dict[str, Any]:
    """h5py ``create_dataset`` keyword arguments for a compression name.

    ``blosc-lz4`` (default: fast), ``zstd`` (smaller), ``gzip`` (readable everywhere, slow), ``lzf``,
    or ``None`` (uncompressed).
    """
    if name is None or name == "none":
        return {}
    if name == "blosc-lz4":
        return dict(hdf5plugin.Blosc(cname="lz4", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE))
    if name == "zstd":
        return dict(hdf5plugin.Zstd(clevel=3))
    if name in ("gzip", "lzf"):
        return {"compression": name, "shuffle": True}
    raise ValueError(f"unknown event-file compression {name!r} (blosc-lz4, zstd, gzip, lzf, none)")


@dataclass
class Events:
    """A batch of events as four aligned arrays: ``t`` (us, int64), ``x``, ``y`` (uint16), ``p`` (int8, +-1)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=np.int64)
        self.x = np.asarray(self.x, dtype=np.uint16)
        self.y = np.asarray(self.y, dtype=np.uint16)
        self.p = np.asarray(self.p, dtype=np.int8)
        n = len(self.t)
        if not (len(self.x) == len(self.y) == len(self.p) == n):
            raise ValueError(
                f"event arrays differ in length: t {n}, x {len(self.x)}, y {len(self.y)}, p {len(self.p)}"
            )

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, idx: slice | np.ndarray) -> Events:
        return Events(self.t[idx], self.x[idx], self.y[idx], self.p[idx])

    @classmethod
    def empty(cls) -> Events:
        return cls(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))

    @classmethod
    def concatenate(cls, parts: list[Events]) -> Events:
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(e, k) for e in parts]) for k in "txyp"))


class EventWriter(CompleteOrAbsent):
    """Append events to a new canonical file in bounded memory.

    Use as a context manager; the file appears under its final name only when the block exits
    without an exception. Timestamps must be non-decreasing across all appends.
    """

    def __init__(
        self,
        path: str | Path,
        width: int,
        height: int,
        provenance: dict[str, Any] | None = None,
        attrs: dict[str, Any] | None = None,
        compression: str | None = "blosc-lz4",
        chunk_events: int = CHUNK_EVENTS,
        t_offset_us: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.width, self.height = int(width), int(height)
        if not (0 < self.width <= MAX_SENSOR_SIDE and 0 < self.height <= MAX_SENSOR_SIDE):
            raise ValueError(f"{self.path}: sensor size {self.width}x{self.height} out of range "
                             f"(1 to {MAX_SENSOR_SIDE} pixels a side)")  # fmt: skip
        self._tmp = self.path.with_name(self.path.name + ".partial")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = h5py.File(self._tmp, "w")
        g = self._f.create_group("events")
        self._ds = {}
        for k, dt in _DTYPES.items():
            self._ds[k] = g.create_dataset(
                k,
                shape=(0,),
                maxshape=(None,),
                dtype=dt,
                chunks=(chunk_events,),
                **compression_options(compression),
            )
        self._n = 0
        self._t_first: int | None = None
        self._t_last: int | None = None
        self._t_offset = t_offset_us
        self._index_key: list[np.ndarray] = []
        self._index: list[np.ndarray] = []
        self._last_bucket: int | None = None
        self._provenance = provenance or {}
        self._attrs = attrs or {}
        self._closed = False

    @property
    def num_events(self) -> int:
        return self._n

    def append(self, events: Events) -> None:
        """Append a batch; raises ``ValueError`` if it would break ordering or the sensor bounds."""
        n = len(events)
        if n == 0:
            return
        t = events.t
        if np.any(np.diff(t) < 0) or (self._t_last is not None and t[0] < self._t_last):
            raise ValueError(f"{self.path}: timestamps must be non-decreasing (at event {self._n})")
        if int(events.x.max()) >= self.width or int(events.y.max()) >= self.height:
            raise ValueError(
                f"{self.path}: coordinates outside the {self.width}x{self.height} sensor (at event {self._n})"
            )
        bad_p = (events.p != 1) & (events.p != -1)
        if np.any(bad_p):
            raise ValueError(
                f"{self.path}: polarity must be -1 or +1 (at event {self._n + int(np.argmax(bad_p))})"
            )
        if self._t_offset is None:
            self._t_offset = int(t[0])
        if self._t_first is None:
            self._t_first = int(t[0])
        for k in "txyp":
            ds = self._ds[k]
            ds.resize((self._n + n,))
            ds[self._n :] = getattr(events, k)
        # Sparse index: the first event of every time bucket that holds events.
        buckets = (t - self._t_offset) // INDEX_STEP_US
        new = np.empty(n, bool)
        new[0] = self._last_bucket is None or buckets[0] != self._last_bucket
        np.not_equal(buckets[1:], buckets[:-1], out=new[1:])
        first = np.flatnonzero(new)
        self._index_key.append(buckets[first].astype(np.int64))
        self._index.append(self._n + first.astype(np.int64))
        self._last_bucket = int(buckets[-1])
        self._n += n
        self._t_last = int(t[-1])

    def close(self) -> Path:
        """Write the index and attributes, and move the file to its final name."""
        if self._closed:
            return self.path
        keys = np.concatenate(self._index_key) if self._index_key else np.zeros(0, np.int64)
        idx = np.concatenate(self._index) if self._index else np.zeros(0, np.int64)
        self._f.create_dataset("t_index_key", data=keys, **compression_options("gzip"))
        self._f.create_dataset("t_index", data=idx, **compression_options("gzip"))
        a = self._f.attrs
        a["format"] = FORMAT_NAME
        a["version"] = FORMAT_VERSION
        a["width"] = self.width
        a["height"] = self.height
        a["time_unit"] = "us"
        a["num_events"] = self._n
        a["t_start_us"] = self._t_first if self._t_first is not None else 0
        a["t_end_us"] = self._t_last if self._t_last is not None else 0
        a["t_offset_us"] = self._t_offset if self._t_offset is not None else 0
        a["index_step_us"] = INDEX_STEP_US
        a["provenance"] = json.dumps(self._provenance, default=str)
        for k, v in self._attrs.items():
            a[k] = json.dumps(v) if isinstance(v, dict | list) else v
        self._f.close()
        os.replace(self._tmp, self.path)
        self._closed = True
        return self.path

    def abort(self) -> None:
        """Close and delete the partial file."""
        if not self._closed:
            try:
                self._f.close()
            finally:
                self._tmp.unlink(missing_ok=True)
                self._closed = True


def write_events(
    path: str | Path,
    events: Events,
    width: int,
    height: int,
    provenance: dict[str, Any] | None = None,
    attrs: dict[str, Any] | None = None,
) -> Path:
    """Write all ``events`` to a new canonical file (convenience for small streams)."""
    with EventWriter(path, width, height, provenance=provenance, attrs=attrs) as w:
        for s in range(0, len(events), CHUNK_EVENTS * 4):
            w.append(events[s : s + CHUNK_EVENTS * 4])
    return Path(path)


class EventFile(Closing):
    """Read a canonical event file by index range or time range without loading all of it."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such event file")
        try:
            self._f = h5py.File(self.path, "r")
        except OSError as e:
            raise ValueError(f"{self.path}: not a readable HDF5 file ({e})") from e
        a = self._f.attrs
        if a.get("format") != FORMAT_NAME or "events" not in self._f:
            self._f.close()
            raise ValueError(
                f"{self.path}: not an evdense event file (format attribute {a.get('format')!r}); "
                "convert it with `evdense convert`"
            )
        try:
            self.version = int(a.get("version", 1))
            if self.version not in (1, 2):
                raise ValueError(f"format version {self.version} (this evdense reads 1 and 2)")
            self.width = int(a["width"])
            self.height = int(a["height"])
            self.num_events = int(a["num_events"])
            self.t_start_us = int(a["t_start_us"])
            self.t_end_us = int(a["t_end_us"])
            self._t_offset = int(a["t_offset_us"])
            self._step = int(a["index_step_us"])
            self._ds = {k: self._f["events"][k] for k in "txyp"}
            lens = {k: len(d) for k, d in self._ds.items()}
            if set(lens.values()) != {self.num_events}:
                raise ValueError(
                    f"event columns hold {lens} entries, num_events says {self.num_events}"
                )
            if not (0 < self.width <= MAX_SENSOR_SIDE and 0 < self.height <= MAX_SENSOR_SIDE):
                raise ValueError(f"sensor size {self.width}x{self.height} out of range")
            if self._step <= 0:
                raise ValueError(f"index_step_us {self._step} must be > 0")
            if self.version == 1:
                self._keys = None
                self._index = self._f["t_index"][()]
            else:
                self._keys = self._f["t_index_key"][()]
                self._index = self._f["t_index"][()]
                if len(self._keys) != len(self._index) or np.any(np.diff(self._keys) <= 0):
                    raise ValueError("damaged time index")
        except (KeyError, ValueError, TypeError, OSError) as e:
            self._f.close()
            raise InputError(self.path, f"damaged evdense event file ({e})") from e
        self._last_t: int | None = None
        self._last_stop = -1

    def close(self) -> None:
        self._f.close()

    def __len__(self) -> int:
        return self.num_events

    @property
    def sensor_size(self) -> tuple[int, int]:
        """``(height, width)`` in pixels."""
        return self.height, self.width

    @property
    def duration_s(self) -> float:
        return (self.t_end_us - self.t_start_us) * 1e-6

    @property
    def attrs(self) -> dict[str, Any]:
        """All file attributes, JSON strings decoded."""
        out: dict[str, Any] = {}
        for k, v in self._f.attrs.items():
            if isinstance(v, bytes):
                v = v.decode()
            if isinstance(v, str) and v[:1] in "{[":
                try:
                    v = json.loads(v)
                except json.JSONDecodeError:
                    pass
            elif isinstance(v, np.generic):
                v = v.item()
            out[k] = v
        return out

    def read(self, start: int = 0, stop: int | None = None) -> Events:
        """Events ``start:stop`` by index (checked: see the module docstring)."""
        stop = self.num_events if stop is None else min(stop, self.num_events)
        start = max(0, min(start, stop))
        try:
            ev = Events(*(self._ds[k][start:stop] for k in "txyp"))
        except (OSError, ValueError) as e:
            raise InputError(self.path, f"cannot read events {start}:{stop} ({e})") from e
        self._check(ev, start)
        return ev

    def _check(self, ev: Events, start: int) -> None:
        if len(ev) == 0:
            return
        bad = np.flatnonzero(np.diff(ev.t) < 0)
        if len(bad):
            i = start + int(bad[0]) + 1
            raise InputError(self.path, f"event {i}: time goes backwards "
                             f"({int(ev.t[bad[0]])} -> {int(ev.t[bad[0] + 1])} us); the file is damaged")  # fmt: skip
        off = (ev.x >= self.width) | (ev.y >= self.height) | ((ev.p != 1) & (ev.p != -1))
        if off.any():
            i = int(np.argmax(off))
            raise InputError(self.path, f"event {start + i}: x={int(ev.x[i])} y={int(ev.y[i])} "
                             f"p={int(ev.p[i])} is not on the {self.width}x{self.height} sensor "
                             "with polarity -1/+1; the file is damaged")  # fmt: skip
        if (
            start > 0
            and self._last_t is not None
            and self._last_stop == start
            and ev.t[0] < self._last_t
        ):
            raise InputError(self.path, f"event {start}: time goes backwards; the file is damaged")
        self._last_t, self._last_stop = int(ev.t[-1]), start + len(ev)

    def read_t(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Timestamps only, ``start:stop`` by index (us)."""
        stop = self.num_events if stop is None else min(stop, self.num_events)
        return self._ds["t"][max(0, start) : stop]

    def index_at(self, t_us: int | float) -> int:
        """Index of the first event with ``t >= t_us``."""
        k = (int(np.ceil(t_us)) - self._t_offset) // self._step
        if self._keys is None:  # version 1: dense index, one entry per step, one past the end
            if k < 0:
                return 0
            if k >= len(self._index) - 1:
                lo, hi = int(self._index[-2]) if len(self._index) > 1 else 0, self.num_events
            else:
                lo, hi = int(self._index[k]), int(self._index[k + 1])
        else:
            j = int(np.searchsorted(self._keys, k, side="left"))
            if j == len(self._keys):
                return self.num_events
            if self._keys[j] > k:  # no event in bucket k: the next bucket's first event
                return int(self._index[j])
            lo = int(self._index[j])
            hi = int(self._index[j + 1]) if j + 1 < len(self._index) else self.num_events
        if lo >= hi:
            return lo
        return lo + int(np.searchsorted(self._ds["t"][lo:hi], t_us, side="left"))

    def read_time(self, t0_us: float, t1_us: float) -> Events:
        """Events with ``t0_us <= t < t1_us``."""
        return self.read(self.index_at(t0_us), self.index_at(t1_us))

    def iter_chunks(
        self, chunk_events: int = 1 << 21, start: int = 0, stop: int | None = None
    ) -> Iterator[Events]:
        """Iterate over consecutive batches of at most ``chunk_events`` events."""
        stop = self.num_events if stop is None else min(stop, self.num_events)
        for s in range(start, stop, chunk_events):
            yield self.read(s, min(s + chunk_events, stop))
