"""Prophesee / Metavision recordings: EVT 2.0 and EVT 3.0 ``.raw`` files and ``.dat`` files.

All three start with ASCII header lines beginning with ``%`` (``% evt 3.0``, ``% format
EVT3;height=720;width=1280``, ``% geometry 1280x720``, ``% Width 640``...), then binary little-endian
data:

- EVT 2.0: 32-bit words, type in bits 31-28. CD_OFF (0x0) / CD_ON (0x1): timestamp low 6 bits in
  27-22, x in 21-11, y in 10-0; EVT_TIME_HIGH (0x8): timestamp bits 33-6 in 27-0.
- EVT 3.0: 16-bit words, type in bits 15-12, decoded with a running state: EVT_ADDR_Y (0x0, y in
  10-0), EVT_ADDR_X (0x2, polarity bit 11, x in 10-0: one event), VECT_BASE_X (0x3, polarity and
  base x), VECT_12 (0x4) / VECT_8 (0x5) (bit masks of events at base x + i; base x then advances by
  12 / 8), EVT_TIME_LOW (0x6) and EVT_TIME_HIGH (0x8) (12 bits each of a 24-bit time base that wraps
  every 16.8 s; a wrap is detected as TIME_HIGH stepping back by more than half its range).
- DAT: two bytes (event type, event size = 8), then 8-byte events: uint32 t (us, wraps every 71.6
  min, unwrapped), uint32 with x in bits 13-0, y in 27-14, polarity in 31-28.

Other word types (triggers, continued, others) are skipped. CD events before the first time base
word have no timestamp: they are dropped and the count is logged. A file whose binary part is not a
whole number of words is truncated: the trailing bytes are dropped with a warning.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from evdense.io._textparse import njit
from evdense.io.base import DEFAULT_CHUNK_EVENTS, RawEvents, Recording, event_buffers
from evdense.log import get_logger

log = get_logger("io")

RAW_WORDS_PER_CHUNK = 1 << 18


def read_header(path: Path) -> tuple[list[str], int]:
    """The ``%`` header lines (without the ``% ``) and the byte offset where binary data starts."""
    lines: list[str] = []
    with open(path, "rb") as f:
        offset = 0
        while True:
            first = f.read(1)
            if first != b"%":
                break
            rest = f.readline()
            line = (first + rest).decode("latin-1").rstrip("\r\n")
            offset += 1 + len(rest)
            lines.append(line[1:].strip())
            if line[1:].strip().lower() == "end":
                break
    return lines, offset


def header_sensor_size(lines: list[str]) -> tuple[int | None, int | None]:
    """Sensor ``(width, height)`` from header lines, or Nones; ``ValueError`` on a malformed size."""
    w = h = None
    for line in lines:
        if re.match(r"(?i)geometry\b", line):
            m = re.fullmatch(r"(?i)geometry\s+(\d+)\s*x\s*(\d+)", line)
            if not m:
                raise ValueError(f"header line {line!r}: expected 'geometry <width>x<height>'")
            w, h = int(m.group(1)), int(m.group(2))
        m = re.match(r"(?i)format\s+(\S+)", line)
        if m:
            for kv in m.group(1).split(";"):
                k, _, v = kv.partition("=")
                if k.lower() in ("width", "height"):
                    if not v.isdigit():
                        raise ValueError(f"header line {line!r}: {k} {v!r} is not a size")
                    if k.lower() == "width":
                        w = int(v)
                    else:
                        h = int(v)
        m = re.match(r"(?i)(width|height)\s+(\S+)$", line)
        if m:
            if not m.group(2).isdigit():
                raise ValueError(f"header line {line!r}: {m.group(2)!r} is not a size")
            if m.group(1).lower() == "width":
                w = int(m.group(2))
            else:
                h = int(m.group(2))
    return w, h


PLUGIN_SENSOR_SIZES = (
    ("genx320", (320, 320)),
    ("imx637", (640, 512)),
    ("imx636", (1280, 720)),
    ("gen41", (1280, 720)),
    ("gen4", (1280, 720)),
    ("gen31", (640, 480)),
    ("gen3", (640, 480)),
)
"""Sensor size of a Metavision HAL plugin (``% plugin_name``), in the order they are matched, for
the older headers that name the plugin but give no ``geometry``."""


def plugin_sensor_size(lines: list[str]) -> tuple[int, int] | None:
    """``(width, height)`` implied by a ``% plugin_name`` header line, or None."""
    for line in lines:
        m = re.match(r"(?i)plugin_name\s+(\S+)", line)
        if m:
            name = m.group(1).lower()
            for key, size in PLUGIN_SENSOR_SIZES:
                if key in name:
                    return size
    return None


def header_encoding(lines: list[str]) -> str | None:
    """ "evt2" / "evt3" / "evt21" from ``% evt X`` or ``% format EVTX`` lines, else None."""
    for line in lines:
        m = re.match(r"(?i)evt\s+(\d)\.(\d)", line)
        if m:
            return {"2.0": "evt2", "3.0": "evt3", "2.1": "evt21"}.get(
                f"{m.group(1)}.{m.group(2)}", "other"
            )
        m = re.match(r"(?i)format\s+(EVT\d+)", line)
        if m:
            return {"EVT2": "evt2", "EVT3": "evt3", "EVT21": "evt21"}.get(
                m.group(1).upper(), "other"
            )
    return None


# --- decoders (state carried between chunks in a small int64 array) -------------------------------
@njit(cache=True, nogil=True)
def _decode_evt2(words, state, t, x, y, p):  # pragma: no cover - compiled
    """state: [time_high, have_time, overflow, dropped_before_time]. Returns the event count."""
    n = 0
    th = state[0]
    have = state[1]
    ovf = state[2]
    for i in range(len(words)):
        w = np.int64(words[i])
        typ = (w >> 28) & 0xF
        if typ == 0x8:
            nth = w & 0x0FFFFFFF
            if have == 1 and nth < th and th - nth > (1 << 27):
                ovf += np.int64(1) << 34
            th = nth
            have = 1
        elif typ == 0x0 or typ == 0x1:
            if have == 0:
                state[3] += 1
                continue
            t[n] = ovf + (th << 6) + ((w >> 22) & 0x3F)
            x[n] = (w >> 11) & 0x7FF
            y[n] = w & 0x7FF
            p[n] = typ
            n += 1
    state[0] = th
    state[1] = have
    state[2] = ovf
    return n


@njit(cache=True, nogil=True)
def _decode_evt3(words, state, t, x, y, p):  # pragma: no cover - compiled
    """state: [y, time_high, time_low, base_x, pol, have_high, have_low, overflow, dropped]."""
    n = 0
    cy = state[0]
    th = state[1]
    tl = state[2]
    bx = state[3]
    pol = state[4]
    hh = state[5]
    hl = state[6]
    ovf = state[7]
    for i in range(len(words)):
        w = np.int64(words[i])
        typ = (w >> 12) & 0xF
        if typ == 0x0:
            cy = w & 0x7FF
        elif typ == 0x2:
            if hh == 0 or hl == 0:
                state[8] += 1
                continue
            t[n] = ovf + (th << 12) + tl
            x[n] = w & 0x7FF
            y[n] = cy
            p[n] = (w >> 11) & 1
            n += 1
        elif typ == 0x3:
            bx = w & 0x7FF
            pol = (w >> 11) & 1
        elif typ == 0x4 or typ == 0x5:
            nb = 12 if typ == 0x4 else 8
            mask = w & 0xFFF if typ == 0x4 else w & 0xFF
            if hh == 0 or hl == 0:
                for b in range(nb):
                    if (mask >> b) & 1:
                        state[8] += 1
            else:
                tt = ovf + (th << 12) + tl
                for b in range(nb):
                    if (mask >> b) & 1:
                        t[n] = tt
                        x[n] = bx + b
                        y[n] = cy
                        p[n] = pol
                        n += 1
            bx += nb
        elif typ == 0x6:
            tl = w & 0xFFF
            hl = 1
        elif typ == 0x8:
            nth = w & 0xFFF
            if hh == 1 and nth < th and th - nth > 2048:
                ovf += np.int64(1) << 24
            th = nth
            hh = 1
    state[0] = cy
    state[1] = th
    state[2] = tl
    state[3] = bx
    state[4] = pol
    state[5] = hh
    state[6] = hl
    state[7] = ovf
    return n


class _PropheseeBase(Recording):
    word_bytes = 4

    def __init__(self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS) -> None:
        super().__init__(path, chunk_events)
        self.header, self.data_offset = read_header(self.path)
        self.width, self.height = header_sensor_size(self.header)
        if self.width is None and self.height is None:
            size = plugin_sensor_size(self.header)
            if size is not None:
                self.width, self.height = size
                self.metadata["sensor_size_from"] = "plugin_name"
        size = self.path.stat().st_size
        self.data_bytes = size - self.data_offset

    def _check_tail(self, unit: int) -> int:
        """Number of whole ``unit``-byte records; warns about (and drops) trailing bytes."""
        n, extra = divmod(self.data_bytes, unit)
        if extra:
            log.warning(
                "%s: the last %d bytes (from byte offset %d) are not a whole %d-byte record: the file "
                "looks truncated; ignored them",
                self.path,
                extra,
                self.data_offset + n * unit,
                unit,
            )
        return n


class RawRecording(_PropheseeBase):
    """EVT 2.0 / EVT 3.0 ``.raw`` files; ``encoding`` "auto" takes it from the header."""

    format = "prophesee_raw"

    def __init__(
        self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS, encoding: str = "auto"
    ) -> None:
        super().__init__(path, chunk_events)
        enc = header_encoding(self.header) if encoding == "auto" else encoding
        if enc is None:
            raise ValueError(
                f"{self.path}: the header does not say the encoding ('% evt 2.0' / '% evt 3.0' / "
                "'% format EVT3'); give the format as evt2 or evt3"
            )
        if enc not in ("evt2", "evt3"):
            raise ValueError(
                f"{self.path}: encoding {enc!r} is not supported (only EVT 2.0 and EVT 3.0)"
            )
        self.encoding = enc
        self.word_bytes = 4 if enc == "evt2" else 2

    def iter_events(self) -> Iterator[RawEvents]:
        nwords = self._check_tail(self.word_bytes)
        dtype = np.dtype("<u4") if self.encoding == "evt2" else np.dtype("<u2")
        mm = (
            np.memmap(self.path, dtype=dtype, mode="r", offset=self.data_offset, shape=(nwords,))
            if nwords
            else []
        )
        state = np.zeros(9, dtype=np.int64)
        decode = _decode_evt2 if self.encoding == "evt2" else _decode_evt3
        per_word = 1 if self.encoding == "evt2" else 12
        step = max(1, min(RAW_WORDS_PER_CHUNK, self.chunk_events // per_word))
        start = 0
        for s in range(0, nwords, step):
            w = np.asarray(mm[s : s + step])
            t, x, y, p = event_buffers(len(w) * per_word)
            n = decode(w, state, t, x, y, p)
            if n:
                off = self.data_offset + s * self.word_bytes
                yield RawEvents(
                    t[:n].copy(),
                    x[:n].copy(),
                    y[:n].copy(),
                    p[:n].copy(),
                    start=start,
                    locate=lambda i, off=off: f"in the words from byte offset {off}",
                )
            start += n
        dropped = int(state[3] if self.encoding == "evt2" else state[8])
        if dropped:
            log.warning(
                "%s: dropped %d CD events that came before the first time base word",
                self.path,
                dropped,
            )
        self.metadata["dropped_before_time_base"] = dropped


class DatRecording(_PropheseeBase):
    """Prophesee ``.dat`` CD event files."""

    format = "prophesee_dat"

    def __init__(self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS) -> None:
        super().__init__(path, chunk_events)
        if self.data_bytes < 2:
            raise ValueError(f"{self.path}: file ends after the header (no event type/size bytes)")
        with open(self.path, "rb") as f:
            f.seek(self.data_offset)
            ev_type, ev_size = f.read(2)
        if ev_size != 8:
            raise ValueError(
                f"{self.path}: event size {ev_size} at byte offset {self.data_offset + 1}; only 8-byte CD "
                "events are supported"
            )
        if ev_type not in (0, 12):
            log.warning(
                "%s: event type %d (expected 0 or 12, CD events); reading as CD", self.path, ev_type
            )
        self.data_offset += 2
        self.data_bytes -= 2

    def iter_events(self) -> Iterator[RawEvents]:
        n = self._check_tail(8)
        if n == 0:
            return
        mm = np.memmap(self.path, dtype="<u4", mode="r", offset=self.data_offset, shape=(n, 2))
        wrap = 0
        last = None
        for s in range(0, n, self.chunk_events):
            c = np.asarray(mm[s : s + self.chunk_events])
            t = c[:, 0].astype(np.int64)
            d = c[:, 1]
            # unwrap the 32-bit microsecond counter: a step back by more than half its range is a wrap
            prev = np.concatenate([[t[0] if last is None else last], t[:-1]])
            wraps = np.cumsum((prev - t) > (1 << 31))
            last = int(t[-1])
            t = t + (wrap + wraps) * (1 << 32)
            wrap += int(wraps[-1])
            off0 = self.data_offset + s * 8
            yield RawEvents(
                t,
                (d & 0x3FFF).astype(np.uint16),
                ((d >> 14) & 0x3FFF).astype(np.uint16),
                ((d >> 28) & 0xF).astype(np.uint8),
                start=s,
                locate=lambda i, off0=off0: f"byte offset {off0 + 8 * i}",
            )


# --- writers (for round-trip tests and for users who need the files) ------------------------------
