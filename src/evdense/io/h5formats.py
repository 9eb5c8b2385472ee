"""HDF5 event files of the E2VID / event_cnn_minimal / EVREAL tooling, and our own canonical file.

E2VID-style layout: ``events/xs``, ``events/ys``, ``events/ts``, ``events/ps`` (one dataset per
field), file attribute ``sensor_resolution`` = ``(height, width)``, optional ``images/imageNNNNNNNNN``
datasets with a ``timestamp`` attribute. ``ts`` is float seconds in the published tools; integer
``ts`` is read as microseconds (``time_unit`` overrides; a ``time_unit``/``ts_unit`` attribute on the
file or dataset is honoured).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np

from evdense.events.container import FORMAT_NAME, EventFile
from evdense.io.base import DEFAULT_CHUNK_EVENTS, Frame, RawEvents, Recording, scale_to_us
from evdense.log import get_logger

log = get_logger("io")

_FIELDS = {"x": ("xs", "x"), "y": ("ys", "y"), "t": ("ts", "t"), "p": ("ps", "p")}
_UNIT_ALIASES = {
    "s": "s",
    "sec": "s",
    "seconds": "s",
    "ms": "ms",
    "us": "us",
    "microseconds": "us",
    "ns": "ns",
}


def _attr_str(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


class E2vidH5Recording(Recording):
    """``events/{xs,ys,ts,ps}`` HDF5 files (E2VID, event_cnn_minimal, EVREAL)."""

    format = "e2vid_h5"

    def __init__(
        self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS, time_unit: str = "auto"
    ) -> None:
        super().__init__(path, chunk_events)
        try:
            self._f = h5py.File(self.path, "r")
        except OSError as e:
            raise ValueError(f"{self.path}: not a readable HDF5 file ({e})") from e
        g = self._f.get("events")
        if not isinstance(g, h5py.Group):
            self._f.close()
            raise ValueError(f"{self.path}: no 'events' group (expected events/xs, ys, ts, ps)")
        self._ds: dict[str, h5py.Dataset] = {}
        for k, names in _FIELDS.items():
            for nm in names:
                if nm in g:
                    self._ds[k] = g[nm]
                    break
            else:
                self._f.close()
                raise ValueError(
                    f"{self.path}: events group lacks '{names[0]}' (found {sorted(g)})"
                )
        lens = {k: d.shape[0] for k, d in self._ds.items()}
        if len(set(lens.values())) != 1:
            self._f.close()
            raise ValueError(
                f"{self.path}: event datasets differ in length {lens} (truncated file?)"
            )
        self.num_events = lens["t"]
        if "sensor_resolution" in self._f.attrs:
            h, w = (int(v) for v in np.asarray(self._f.attrs["sensor_resolution"])[:2])
            self.width, self.height = w, h
        if time_unit == "auto":
            a = dict(self._f.attrs) | dict(self._ds["t"].attrs)
            for key in ("time_unit", "ts_unit", "t_unit", "unit"):
                if key in a and _attr_str(a[key]).lower() in _UNIT_ALIASES:
                    time_unit = _UNIT_ALIASES[_attr_str(a[key]).lower()]
                    break
            else:
                time_unit = "s" if np.issubdtype(self._ds["t"].dtype, np.floating) else "us"
            log.info("%s: timestamps (%s) read as %s", self.path, self._ds["t"].dtype, time_unit)
        self.time_unit = time_unit
        if self._ds["t"].dtype == np.float32 and time_unit == "s" and self.num_events:
            tmax = float(np.abs(self._ds["t"][[0, self.num_events - 1]]).max())
            if tmax * 2**-24 > 1e-6:
                log.warning(
                    "%s: float32 timestamps up to %.1f s are only precise to %.0f us",
                    self.path,
                    tmax,
                    tmax * 2**-24 * 1e6,
                )

    def close(self) -> None:
        self._f.close()

    def iter_events(self) -> Iterator[RawEvents]:
        n = self.num_events
        for s in range(0, n, self.chunk_events):
            e = min(s + self.chunk_events, n)
            t = scale_to_us(self._ds["t"][s:e], self.time_unit, self.path, s)
            yield RawEvents(t, self._ds["x"][s:e], self._ds["y"][s:e], self._ds["p"][s:e], start=s)

    def iter_frames(self) -> Iterator[Frame]:
        g = self._f.get("images")
        if not isinstance(g, h5py.Group):
            return
        for name in sorted(g):
            d = g[name]
            if "timestamp" not in d.attrs:
                raise ValueError(f"{self.path}: images/{name} has no 'timestamp' attribute")
            ts = np.asarray([d.attrs["timestamp"]])
            unit = "s" if np.issubdtype(ts.dtype, np.floating) else self.time_unit
            t_us = int(scale_to_us(ts, unit, self.path)[0])
            img = d[()]
            if img.dtype != np.uint8:
                raise ValueError(f"{self.path}: images/{name} is {img.dtype}, expected uint8")
            yield Frame(t_us, image=img)


class CanonicalH5Recording(Recording):
    """Our own canonical event file used as an input (copied, re-validated)."""

    format = "evdense"

    def __init__(self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS) -> None:
        super().__init__(path, chunk_events)
        self._ef = EventFile(self.path)
        self.width, self.height = self._ef.width, self._ef.height

    def close(self) -> None:
        self._ef.close()

    def iter_events(self) -> Iterator[RawEvents]:
        for s in range(0, self._ef.num_events, self.chunk_events):
            ev = self._ef.read(s, s + self.chunk_events)
            yield RawEvents(ev.t, ev.x, ev.y, ev.p, start=s)


def is_canonical_h5(path: str | Path) -> bool:
    """True when ``path`` is an evdense canonical event file."""
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") == FORMAT_NAME
    except OSError:
        return False
