"""NumPy event files: a ``.npy`` structured array, or a ``.npz`` with one array per field.

Field names: timestamp ``t``/``ts``/``timestamp``/``timestamps``, ``x``, ``y``, polarity
``p``/``polarity``/``pol``/``ps`` (``xs``/``ys`` accepted too). Integer timestamps are read as
microseconds, float timestamps as seconds (``time_unit`` overrides). Both are streamed: ``.npy``
through a memory map, ``.npz`` members through their zip stream (compressed or not), so memory stays
bounded. A ``.npz`` may carry ``width``/``height`` (or ``sensor_size`` = (height, width)) scalars.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from evdense.io.base import DEFAULT_CHUNK_EVENTS, RawEvents, Recording, scale_to_us
from evdense.log import get_logger

log = get_logger("io")

NAMES = {
    "t": ("t", "ts", "timestamp", "timestamps", "time"),
    "x": ("x", "xs"),
    "y": ("y", "ys"),
    "p": ("p", "polarity", "pol", "ps", "polarities"),
}


def _pick(names: list[str], path: Path) -> dict[str, str]:
    out = {}
    for k, cands in NAMES.items():
        for c in cands:
            if c in names:
                out[k] = c
                break
        else:
            raise ValueError(f"{path}: no field for {k!r} (looked for {cands}; found {names})")
    return out


def _default_unit(dtype: np.dtype, unit: str) -> str:
    if unit != "auto":
        return unit
    return "s" if np.issubdtype(dtype, np.floating) else "us"


class _NpyMember:
    """One ``.npy`` stream inside a zip, read in pieces."""

    def __init__(self, zf: zipfile.ZipFile, name: str, path: Path) -> None:
        self.zf, self.name, self.path = zf, name, path
        with zf.open(name) as f:
            self.shape, self.fortran, self.dtype = self._header(f)
        if len(self.shape) != 1:
            raise ValueError(f"{path}: {name} has shape {self.shape}, expected one dimension")

    def _header(self, f: IO[bytes]):
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            return np.lib.format.read_array_header_1_0(f)
        return np.lib.format.read_array_header_2_0(f)

    def chunks(self, n: int) -> Iterator[np.ndarray]:
        with self.zf.open(self.name) as f:
            self._header(f)
            total = self.shape[0]
            done = 0
            while done < total:
                k = min(n, total - done)
                buf = f.read(k * self.dtype.itemsize)
                if len(buf) < k * self.dtype.itemsize:
                    raise ValueError(
                        f"{self.path}: {self.name} ends after {done + len(buf) // self.dtype.itemsize} of "
                        f"{total} elements (truncated file)"
                    )
                yield np.frombuffer(buf, dtype=self.dtype)
                done += k


class NumpyRecording(Recording):
    """``.npy`` structured arrays and ``.npz`` archives of named event fields."""

    format = "numpy"

    def __init__(
        self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS, time_unit: str = "auto"
    ) -> None:
        super().__init__(path, chunk_events)
        self._zf: zipfile.ZipFile | None = None
        if self.path.suffix.lower() == ".npz":
            try:
                self._zf = zipfile.ZipFile(self.path)
            except zipfile.BadZipFile as e:
                raise ValueError(f"{self.path}: not a readable .npz archive ({e})") from e
            members = {n[:-4]: n for n in self._zf.namelist() if n.endswith(".npy")}
            self._names = _pick(list(members), self.path)
            self._members = {
                k: _NpyMember(self._zf, members[v], self.path) for k, v in self._names.items()
            }
            lens = {k: m.shape[0] for k, m in self._members.items()}
            if len(set(lens.values())) != 1:
                raise ValueError(f"{self.path}: fields differ in length {lens}")
            self.num_events = lens["t"]
            t_dtype = self._members["t"].dtype
            self._read_size_npz(members)
        else:
            try:
                self._arr = np.load(self.path, mmap_mode="r", allow_pickle=False)
            except ValueError as e:
                raise ValueError(f"{self.path}: not a readable .npy file ({e})") from e
            if self._arr.dtype.names is None:
                raise ValueError(
                    f"{self.path}: a plain {self._arr.dtype} array of shape {self._arr.shape}; "
                    "expected a structured array with named fields (t, x, y, p)"
                )
            self._names = _pick(list(self._arr.dtype.names), self.path)
            self.num_events = len(self._arr)
            t_dtype = self._arr.dtype[self._names["t"]]
        self.time_unit = _default_unit(t_dtype, time_unit)
        log.info("%s: timestamps (%s) read as %s", self.path, t_dtype, self.time_unit)

    def _read_size_npz(self, members: dict[str, str]) -> None:
        assert self._zf is not None
        with np.load(self.path, allow_pickle=False) as z:
            if "width" in members and "height" in members:
                self.width, self.height = int(z["width"]), int(z["height"])
            elif "sensor_size" in members:
                h, w = (int(v) for v in np.asarray(z["sensor_size"]).ravel()[:2])
                self.width, self.height = w, h

    def close(self) -> None:
        if self._zf is not None:
            self._zf.close()

    def iter_events(self) -> Iterator[RawEvents]:
        n = self.chunk_events
        if self._zf is not None:
            its = {k: m.chunks(n) for k, m in self._members.items()}
            start = 0
            for t in its["t"]:
                x, y, p = next(its["x"]), next(its["y"]), next(its["p"])
                yield RawEvents(
                    scale_to_us(t, self.time_unit, self.path, start), x, y, p, start=start
                )
                start += len(t)
            return
        a = self._arr
        nm = self._names
        for s in range(0, self.num_events, n):
            c = a[s : s + n]
            t = scale_to_us(np.asarray(c[nm["t"]]), self.time_unit, self.path, s)
            yield RawEvents(
                t, np.asarray(c[nm["x"]]), np.asarray(c[nm["y"]]), np.asarray(c[nm["p"]]), start=s
            )
