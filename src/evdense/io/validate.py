"""Checks on a raw event stream before it reaches the canonical file.

Every problem ends in one of two ways: a ``ValueError`` naming the file and the position of the
first offending event (stream index plus line number or byte offset), or an explicit correction
that is logged with its count. Nothing is changed silently.

- Polarity: 0/1, -1/+1 and bool are accepted and mapped to -1/+1. Any other value, or a stream
  that mixes 0 and -1, is an error.
- Coordinates: negative values are always an error; values outside the sensor are an error
  (``out_of_bounds="error"``) or dropped and counted (``"drop"``).
- Timestamps: integer microseconds in ``[0, MAX_TIME_US]`` (2^53 us, about 285 years: every
  such value is exact in a float64 too); a negative, unsigned-overflowed or absurd timestamp is an
  error.
- Sensor size: each side in ``[1, MAX_SENSOR_SIDE]`` (8192 pixels; the largest event sensors have
  1280 x 960), checked before anything is allocated from it.
- Time order: with ``unsorted="error"`` the first step back in time is an error. With ``"sort"``
  (default) events are re-ordered through a buffer that holds the last ``reorder_window_us``
  microseconds of the stream, so memory stays bounded by the event rate times the window. An
  event more than ``reorder_window_us`` behind the latest timestamp before it is an error asking
  for a larger window (whatever the batch size, so the outcome does not depend on chunking).
  Equal timestamps keep their file order.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from evdense.events.container import Events
from evdense.io.base import RawEvents
from evdense.log import get_logger

log = get_logger("io")

MAX_TIME_US = 1 << 53
"""Largest timestamp accepted, microseconds."""
MAX_SENSOR_SIDE = 8192
"""Largest sensor width or height accepted, pixels."""


def check_sensor_size(
    width: object, height: object, path: str | Path, source: str
) -> tuple[int, int]:
    """``(width, height)`` as ints when both are in ``[1, MAX_SENSOR_SIDE]``, else ``InputError``."""
    from evdense.errors import InputError

    try:
        w, h = int(width), int(height)  # type: ignore[call-overload]
    except (TypeError, ValueError, OverflowError) as e:
        raise InputError(
            path, f"sensor size {width!r} x {height!r} ({source}) is not a pair of integers"
        ) from e
    if not (1 <= w <= MAX_SENSOR_SIDE and 1 <= h <= MAX_SENSOR_SIDE):
        raise InputError(path, f"sensor size {w} x {h} ({source}) is out of range: each side must be "
                         f"1 to {MAX_SENSOR_SIDE} pixels")  # fmt: skip
    return w, h


def _times(raw: RawEvents, path: Path) -> None:
    t = raw.t
    bad = (t < 0) | (t > MAX_TIME_US)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{path}: timestamp {int(t[i])} us at {raw.where(i)} is out of range "
                         f"(0 to 2^53 us); the file is damaged or its time unit is wrong")  # fmt: skip


@dataclass
class ValidationConfig:
    """How to treat imperfect event streams."""

    unsorted: Literal["sort", "error"] = "sort"
    """Out-of-order timestamps: re-order them within the window ("sort") or stop ("error")."""
    reorder_window_us: int = 10_000
    """How far back in time (microseconds) an event may arrive and still be sorted into place."""
    out_of_bounds: Literal["error", "drop"] = "error"
    """Events outside the sensor: stop with an error, or drop them and log how many."""


@dataclass
class ValidationReport:
    """What the checks found and changed, for logs and the ingest manifest."""

    events_in: int = 0
    events_out: int = 0
    out_of_order: int = 0
    max_step_back_us: int = 0
    dropped_out_of_bounds: int = 0
    polarity_encoding: str = "unknown"
    corrections: list[str] = field(default_factory=list)


def _polarity(raw: RawEvents, path: Path, state: dict) -> np.ndarray:
    """Map a batch's polarity to int8 -1/+1, checking its encoding against the stream's so far."""
    p = raw.p
    if p.dtype == np.bool_:
        state.setdefault("enc", "bool")
        return np.where(p, 1, -1).astype(np.int8)
    if np.issubdtype(p.dtype, np.floating):
        bad = ~np.isin(p, (0.0, 1.0, -1.0))
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"{path}: polarity {p[i]} at {raw.where(i)}; expected 0/1 or -1/+1")
        p = p.astype(np.int64)
    is_zero = p == 0
    is_neg = p == -1
    bad = ~(is_zero | is_neg | (p == 1))
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{path}: polarity {p[i]} at {raw.where(i)}; expected 0/1 or -1/+1")
    # the encoding is fixed by the first 0 or -1 seen; the other one later is an error
    seen = [
        (int(np.argmax(off)), value, enc, other_value, other_enc)
        for off, value, enc, other_value, other_enc in (
            (is_zero, "0", "0/1", "-1", "-1/+1"),
            (is_neg, "-1", "-1/+1", "0", "0/1"),
        )
        if off.any()
    ]
    for i, value, enc, other_value, other_enc in sorted(seen):
        if state.get("enc") == other_enc:
            raise ValueError(
                f"{path}: polarity {value} at {raw.where(i)} in a stream that uses {other_enc} "
                f"(first {other_value} at event {state['first']}); mixed polarity encodings"
            )
        if "enc" not in state:
            state["enc"], state["first"] = enc, raw.start + i
    out = np.ones(len(p), dtype=np.int8)
    out[is_zero | is_neg] = -1
    return out


def _bounds(
    raw: RawEvents,
    path: Path,
    width: int,
    height: int,
    cfg: ValidationConfig,
    report: ValidationReport,
) -> np.ndarray | None:
    """Check coordinates; returns a keep-mask when events must be dropped, else None."""
    x, y = raw.x, raw.y
    if np.issubdtype(x.dtype, np.signedinteger) or np.issubdtype(y.dtype, np.signedinteger):
        neg = (x < 0) | (y < 0)
        if neg.any():
            i = int(np.argmax(neg))
            raise ValueError(f"{path}: negative coordinate (x={x[i]}, y={y[i]}) at {raw.where(i)}")
    if np.issubdtype(x.dtype, np.floating) or np.issubdtype(y.dtype, np.floating):
        frac = (x != np.floor(x)) | (y != np.floor(y))
        if frac.any():
            i = int(np.argmax(frac))
            raise ValueError(
                f"{path}: non-integer coordinate (x={x[i]}, y={y[i]}) at {raw.where(i)}"
            )
    outside = (x >= width) | (y >= height)
    if not outside.any():
        return None
    if cfg.out_of_bounds == "error":
        i = int(np.argmax(outside))
        raise ValueError(
            f"{path}: event at (x={x[i]}, y={y[i]}) is outside the {width}x{height} sensor at "
            f"{raw.where(i)}; give the right sensor size (dataset keys width/height, "
            "`evdense convert --width/--height`) or set ingest.out_of_bounds: drop"
        )
    report.dropped_out_of_bounds += int(outside.sum())
    return ~outside


class _Orderer:
    """Bounded re-ordering of nearly sorted batches (see the module docstring)."""

    def __init__(self, path: Path, cfg: ValidationConfig, report: ValidationReport) -> None:
        self.path, self.cfg, self.report = path, cfg, report
        self.pending: Events | None = None
        self.seen_max: int | None = None  # largest timestamp seen so far
        self.emitted_last: int | None = None  # timestamp of the last event handed on

    def push(self, ev: Events, raw: RawEvents, keep: np.ndarray | None) -> Iterator[Events]:
        t = ev.t
        n = len(t)
        if n == 0:
            return
        prev = self.seen_max if self.seen_max is not None else np.iinfo(np.int64).min
        in_order = bool(t[0] >= prev) and bool(np.all(t[1:] >= t[:-1]))  # the common, fast case
        if in_order:
            back = np.zeros(0, dtype=bool)
            ref = t
        else:
            # ref[i]: the largest timestamp before event i (in this batch or earlier ones)
            ref = np.maximum.accumulate(np.concatenate([[prev], t]))[:-1]
            back = t < ref
        if back.any():

            def where(i: int) -> str:  # position in the raw batch (before any drop)
                return raw.where(int(np.flatnonzero(keep)[i]) if keep is not None else i)

            i = int(np.argmax(back))
            if self.cfg.unsorted == "error":
                raise ValueError(
                    f"{self.path}: timestamps go back in time at {where(i)}: "
                    f"{int(t[i])} us after {int(ref[i])} us (ingest.unsorted: error)"
                )
            self.report.out_of_order += int(back.sum())
            steps = ref - t
            step = int(steps[back].max())
            self.report.max_step_back_us = max(self.report.max_step_back_us, step)
            late = back & (steps > self.cfg.reorder_window_us)
            if late.any():
                j = int(np.argmax(late))
                raise ValueError(
                    f"{self.path}: {where(j)} has t={int(t[j])} us, {int(steps[j])} us behind "
                    f"an earlier event: beyond the reorder window ({self.cfg.reorder_window_us} us); "
                    "raise ingest.reorder_window_us or sort the recording first"
                )
            # what was handed on is at most seen_max - window, so it cannot be overtaken
            assert self.emitted_last is None or int(t.min()) >= self.emitted_last
        self.seen_max = int(t[-1]) if in_order else max(int(ref[-1]), int(t[-1]))
        if self.pending is None and in_order:
            self.emitted_last = int(t[-1])
            yield ev
            return
        if self.pending is not None and len(self.pending):
            merged = Events.concatenate([self.pending, ev])
        else:
            merged = ev
        if not in_order:
            merged = merged[np.argsort(merged.t, kind="stable")]
        cut = int(
            np.searchsorted(merged.t, self.seen_max - self.cfg.reorder_window_us, side="right")
        )
        if cut:
            self.emitted_last = int(merged.t[cut - 1])
            yield merged[:cut]
        self.pending = merged[cut:]

    def flush(self) -> Iterator[Events]:
        if self.pending is not None and len(self.pending):
            self.emitted_last = int(self.pending.t[-1])
            yield self.pending
        self.pending = None


def validate_stream(
    batches: Iterable[RawEvents],
    path: str | Path,
    width: int,
    height: int,
    cfg: ValidationConfig | None = None,
    report: ValidationReport | None = None,
) -> Iterator[Events]:
    """Check and normalise raw batches into canonical :class:`Events` for a ``width`` x ``height`` sensor.

    Fills ``report`` (when given) with counts; logs every correction as a warning when the stream
    ends. Raises ``ValueError`` naming ``path`` and the event position on errors (see module doc).
    """
    path = Path(path)
    cfg = cfg or ValidationConfig()
    report = report if report is not None else ValidationReport()
    pol_state: dict = {}
    order = _Orderer(path, cfg, report)
    for raw in batches:
        n = len(raw)
        if n == 0:
            continue
        report.events_in += n
        if raw.t.dtype != np.int64:
            raise ValueError(f"{path}: timestamps are {raw.t.dtype}, expected int64 microseconds")
        _times(raw, path)
        p = _polarity(raw, path, pol_state)
        keep = _bounds(raw, path, width, height, cfg, report)
        x, y, t = raw.x, raw.y, raw.t
        if keep is not None:
            t, x, y, p = t[keep], x[keep], y[keep], p[keep]
        ev = Events(t, x, y, p)
        for out in order.push(ev, raw, keep):
            report.events_out += len(out)
            yield out
    for out in order.flush():
        report.events_out += len(out)
        yield out
    report.polarity_encoding = pol_state.get("enc", report.polarity_encoding)
    if report.out_of_order:
        msg = (
            f"sorted {report.out_of_order} out-of-order events (largest step back "
            f"{report.max_step_back_us} us)"
        )
        report.corrections.append(msg)
        log.warning("%s: %s", path, msg)
    if report.dropped_out_of_bounds:
        msg = f"dropped {report.dropped_out_of_bounds} events outside the {width}x{height} sensor"
        report.corrections.append(msg)
        log.warning("%s: %s", path, msg)


def infer_sensor_size(batches: Iterable[RawEvents], path: str | Path) -> tuple[int, int]:
    """Sensor ``(width, height)`` in pixels as ``max + 1`` of the coordinates (one pass over the stream)."""
    mx = my = -1
    for raw in batches:
        if len(raw):
            mx = max(mx, int(raw.x.max()))
            my = max(my, int(raw.y.max()))
    if mx < 0 or my < 0:
        raise ValueError(
            f"{path}: no events (or only negative coordinates); cannot infer the sensor size"
        )
    return mx + 1, my + 1
