"""What every reader of a real recording provides: raw event batches, the sensor size it knows,
and whatever side data the recording carries (frames, calibration, ground-truth trajectory).

A reader yields :class:`RawEvents`: timestamps already in microseconds (int64), coordinates and
polarity still as the file stores them (any integer or bool dtype), so that
:mod:`evdense.io.validate` can check them before they are narrowed to the canonical dtypes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from evdense.camera import Camera
from evdense.formats.files import Closing

DEFAULT_CHUNK_EVENTS = 1 << 20


@dataclass
class RawEvents:
    """A batch of events as read from a file, before validation.

    ``t`` is int64 microseconds; ``x``, ``y`` (pixels) and ``p`` keep the file's dtype.
    ``start`` is the index of the batch's first event in the whole stream; ``locate(i)`` names
    where batch event ``i`` sits in the file ("line 12", "byte offset 4096") for error messages.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    start: int = 0
    locate: Callable[[int], str] | None = None

    def __len__(self) -> int:
        return len(self.t)

    def where(self, i: int) -> str:
        """Human-readable position of batch event ``i``: stream index plus file position."""
        s = f"event {self.start + i}"
        if self.locate is not None:
            s += f" ({self.locate(i)})"
        return s


def event_buffers(
    cap: int, xy_dtype: type = np.uint16, p_dtype: type = np.uint8
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Empty ``t`` (int64), ``x``, ``y`` and ``p`` arrays of ``cap`` events for a decoder to fill."""
    return (
        np.empty(cap, np.int64),
        np.empty(cap, xy_dtype),
        np.empty(cap, xy_dtype),
        np.empty(cap, p_dtype),
    )


@dataclass
class Frame:
    """One conventional (APS) frame: ``t_us`` microseconds, ``image`` ``(H, W)`` or ``(H, W, 3)`` uint8,
    or ``source`` a file that already holds the image (copied as is when it is a PNG)."""

    t_us: int
    image: np.ndarray | None = None
    source: Path | None = None


@dataclass
class Trajectory:
    """Ground-truth camera-to-world poses: ``t`` ``(N,)`` seconds, ``T_wc`` ``(N, 4, 4)``."""

    t: np.ndarray
    T_wc: np.ndarray
    source: str = ""


class Recording(Closing):
    """An opened recording. Subclasses set ``format`` and implement :meth:`iter_events`.

    ``width``/``height`` are the sensor size the file states (pixels), or None when it does not.
    """

    format: ClassVar[str] = ""

    def __init__(self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such recording")
        self.chunk_events = int(chunk_events)
        self.width: int | None = None
        self.height: int | None = None
        self.metadata: dict[str, Any] = {}

    def iter_events(self) -> Iterator[RawEvents]:
        """Yield batches of at most about ``chunk_events`` events, in file order."""
        raise NotImplementedError

    def iter_frames(self) -> Iterator[Frame]:
        """Yield the conventional frames the recording holds (none by default)."""
        return iter(())

    def camera(self, width: int, height: int) -> Camera | None:
        """Intrinsics stored with the recording, for a ``width`` x ``height`` sensor, or None."""
        return None

    def trajectory(self) -> Trajectory | None:
        """Ground-truth trajectory stored with the recording, or None."""
        return None


def seconds_to_us(ts: np.ndarray, path: Path, start: int = 0) -> np.ndarray:
    """Float seconds ``(N,)`` to int64 microseconds (rounded to nearest).

    float64 holds absolute Unix times (~1.7e9 s) to ~0.12 us, so rounding recovers the exact
    microsecond. Raises ``ValueError`` naming the file and event on NaN or infinite values.
    """
    ts = np.asarray(ts, dtype=np.float64)
    bad = ~np.isfinite(ts)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{path}: timestamp of event {start + i} is {ts[i]} (not a finite number)")
    bad = np.abs(ts) > 2.0**53 * 1e-6
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{path}: timestamp of event {start + i} is {ts[i]} s (out of range)")
    return np.rint(ts * 1e6).astype(np.int64)


def scale_to_us(ts: np.ndarray, unit: str, path: Path, start: int = 0) -> np.ndarray:
    """Timestamps in ``unit`` ("s", "ms", "us", "ns") to int64 microseconds."""
    if unit == "s":
        return seconds_to_us(ts, path, start)
    if unit == "ms":
        return seconds_to_us(np.asarray(ts, dtype=np.float64) * 1e-3, path, start)
    if unit == "us":
        if np.issubdtype(np.asarray(ts).dtype, np.floating):
            return seconds_to_us(np.asarray(ts, dtype=np.float64) * 1e-6, path, start)
        return np.asarray(ts, dtype=np.int64)
    if unit == "ns":
        t = np.asarray(ts)
        if np.issubdtype(t.dtype, np.floating):
            return seconds_to_us(t.astype(np.float64) * 1e-9, path, start)
        t = t.astype(np.int64)
        return (t + 500) // 1000
    raise ValueError(f"{path}: unknown time unit {unit!r} (expected s, ms, us or ns)")
