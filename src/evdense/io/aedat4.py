"""AEDAT 4.0 files from iniVation cameras (DAVIS346, DVXplorer), decoded without dv-processing.

Layout (little-endian):

- the line ``#!AER-DAT4.0\\r\\n``;
- an int32 size, then the IOHeader flatbuffer (identifier ``IOHE``): compression (int32 enum:
  0 none, 1 LZ4, 2 LZ4 high, 3 ZSTD, 4 ZSTD high), dataTablePosition (int64 byte offset of the
  file data table, -1 when absent), infoNode (XML string describing each stream: typeIdentifier,
  and ``info/sizeX``, ``info/sizeY``);
- packets until the data table (or the end of the file): int32 stream id, int32 byte size, then
  that many bytes: one compressed, size-prefixed flatbuffer whose identifier gives its type.
  ``EVTS`` (EventPacket): a vector of 16-byte structs ``int64 timestamp (us), int16 x, int16 y,
  bool polarity, 3 bytes padding``. ``FRME`` (Frame): timestamp (exposure midpoint, us), format
  (0 gray, 16 BGR, 24 BGRA), sizeX, sizeY, pixels. Other types (IMUS, TRIG) are skipped.

Only the first event stream and the first frame stream are read (others are logged). A file that
ends inside a packet is truncated: the incomplete last packet is dropped with a warning; a packet
that does not decompress or parse is an error naming its byte offset.
"""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evdense.io.base import DEFAULT_CHUNK_EVENTS, Frame, RawEvents, Recording
from evdense.log import get_logger

log = get_logger("io")

MAGIC = b"#!AER-DAT4.0"
COMPRESSION = {0: "NONE", 1: "LZ4", 2: "LZ4_HIGH", 3: "ZSTD", 4: "ZSTD_HIGH"}
EVENT_DTYPE = np.dtype(
    {
        "names": ["t", "x", "y", "p"],
        "formats": ["<i8", "<i2", "<i2", "u1"],
        "offsets": [0, 8, 10, 12],
        "itemsize": 16,
    }
)


# --- a minimal flatbuffer reader -----------------------------------------------------------------
class _Table:
    """A flatbuffer table at ``pos`` in ``buf`` (offsets relative to ``buf``)."""

    def __init__(self, buf: bytes, pos: int) -> None:
        self.buf, self.pos = buf, pos
        self.vt = pos - struct.unpack_from("<i", buf, pos)[0]
        self.vt_size = struct.unpack_from("<H", buf, self.vt)[0]

    def _off(self, slot: int) -> int:
        o = 4 + 2 * slot
        if o + 2 > self.vt_size:
            return 0
        return struct.unpack_from("<H", self.buf, self.vt + o)[0]

    def scalar(self, slot: int, fmt: str, default: int | float = 0):
        o = self._off(slot)
        return default if o == 0 else struct.unpack_from("<" + fmt, self.buf, self.pos + o)[0]

    def vector(self, slot: int) -> tuple[int, int]:
        """(byte position of the first element, element count); (0, 0) when absent."""
        o = self._off(slot)
        if o == 0:
            return 0, 0
        at = self.pos + o
        vpos = at + struct.unpack_from("<I", self.buf, at)[0]
        n = struct.unpack_from("<I", self.buf, vpos)[0]
        return vpos + 4, n

    def string(self, slot: int) -> str:
        start, n = self.vector(slot)
        return self.buf[start : start + n].decode("utf-8", errors="replace")


def _root(fb: bytes) -> tuple[_Table, bytes]:
    """Root table and file identifier of a (not size-prefixed) flatbuffer."""
    return _Table(fb, struct.unpack_from("<I", fb, 0)[0]), fb[4:8]


# --- a minimal flatbuffer writer (for tests and round trips) -------------------------------------


# --- the reader -----------------------------------------------------------------------------------
@dataclass
class _Stream:
    id: int
    type: str
    name: str
    width: int | None
    height: int | None


def _decompressor(code: int, path: Path):
    if code == 0:
        return lambda b: b
    if code in (1, 2):
        import lz4.frame

        return lz4.frame.decompress
    if code in (3, 4):
        try:
            from compression import zstd  # type: ignore[import-not-found]  # Python >= 3.14
        except ImportError:
            try:
                from backports import zstd  # type: ignore[no-redef]
            except ImportError:
                try:
                    import zstandard as zstd  # type: ignore[no-redef]
                except ImportError as e:
                    raise ValueError(
                        f"{path}: ZSTD-compressed AEDAT4 needs the 'backports.zstd' or 'zstandard' package"
                    ) from e
        return zstd.decompress
    raise ValueError(f"{path}: unknown AEDAT4 compression code {code}")


class Aedat4Recording(Recording):
    """AEDAT 4.0 recordings: events of the first event stream, frames of the first frame stream."""

    format = "aedat4"

    def __init__(self, path: str | Path, chunk_events: int = DEFAULT_CHUNK_EVENTS) -> None:
        super().__init__(path, chunk_events)
        with open(self.path, "rb") as f:
            line = f.readline()
            if not line.startswith(MAGIC):
                raise ValueError(f"{self.path}: not an AEDAT 4.0 file (first line {line[:20]!r})")
            head = f.read(4)
            if len(head) < 4:
                raise ValueError(
                    f"{self.path}: file ends inside the header (byte offset {len(line)})"
                )
            (size,) = struct.unpack("<i", head)
            fb = f.read(size)
            if size <= 0 or len(fb) < size:
                raise ValueError(
                    f"{self.path}: IOHeader of {size} bytes at byte offset {len(line)} is incomplete"
                )
        try:
            hdr, ident = _root(fb)
            if ident != b"IOHE":
                raise ValueError(f"identifier {ident!r}")
            self.compression = int(hdr.scalar(0, "i", 0))
            self.data_table_position = int(hdr.scalar(1, "q", -1))
            info = hdr.string(2)
        except (struct.error, ValueError) as e:
            raise ValueError(
                f"{self.path}: corrupt IOHeader at byte offset {len(line)} ({e})"
            ) from e
        self._first_packet = len(line) + 4 + size
        self._decompress = _decompressor(self.compression, self.path)
        self.streams = self._parse_info(info)
        self.metadata["compression"] = COMPRESSION.get(self.compression, str(self.compression))
        self.metadata["streams"] = {s.id: f"{s.name} ({s.type})" for s in self.streams}
        ev = [s for s in self.streams if s.type == "EVTS"]
        fr = [s for s in self.streams if s.type == "FRME"]
        self.event_stream = ev[0].id if ev else None
        self.frame_stream = fr[0].id if fr else None
        if len(ev) > 1:
            log.warning(
                "%s: %d event streams; reading stream %d (%s) only",
                self.path,
                len(ev),
                ev[0].id,
                ev[0].name,
            )
        if ev:
            self.width, self.height = ev[0].width, ev[0].height
        elif not ev:
            log.warning("%s: no event stream (EVTS) in the header", self.path)

    def _parse_info(self, xml: str) -> list[_Stream]:
        try:
            root = ET.fromstring(xml)
        except ET.ParseError as e:
            raise ValueError(
                f"{self.path}: the IOHeader's stream description is not valid XML ({e})"
            ) from e
        out = []
        for node in root.iter("node"):
            if not node.get("name", "").isdigit():
                continue
            attrs = {a.get("key"): a.text for a in node.findall("attr")}
            info = {}
            for sub in node.findall("node"):
                if sub.get("name") == "info":
                    info = {a.get("key"): a.text for a in sub.findall("attr")}
            w, h = info.get("sizeX"), info.get("sizeY")
            out.append(
                _Stream(
                    id=int(node.get("name", "0")),
                    type=attrs.get("typeIdentifier") or "",
                    name=attrs.get("originalOutputName") or "",
                    width=int(w) if w else None,
                    height=int(h) if h else None,
                )
            )
        return out

    def _packets(self, want: int | None) -> Iterator[tuple[int, bytes]]:
        """Yield ``(byte offset, decompressed flatbuffer)`` of each packet of stream ``want``."""
        if want is None:
            return
        end = self.data_table_position if self.data_table_position > 0 else None
        with open(self.path, "rb") as f:
            f.seek(0, 2)
            size = f.tell()
            end = size if end is None else min(end, size)
            pos = self._first_packet
            f.seek(pos)
            while pos < end:
                head = f.read(8)
                if len(head) < 8 or pos + 8 + struct.unpack("<ii", head)[1] > end:
                    log.warning(
                        "%s: the file ends inside the packet at byte offset %d: it looks truncated; "
                        "ignored that packet",
                        self.path,
                        pos,
                    )
                    return
                sid, n = struct.unpack("<ii", head)
                if n < 0:
                    raise ValueError(
                        f"{self.path}: packet at byte offset {pos} has a negative size {n}"
                    )
                if sid != want:
                    f.seek(n, 1)
                    pos += 8 + n
                    continue
                data = f.read(n)
                try:
                    raw = self._decompress(data)
                    (fb_size,) = struct.unpack_from("<I", raw, 0)
                    if fb_size + 4 > len(raw):
                        raise ValueError(f"size prefix {fb_size} > {len(raw) - 4} bytes")
                except Exception as e:  # noqa: BLE001 - any decoder failure is a corrupt packet
                    raise ValueError(
                        f"{self.path}: packet of stream {sid} at byte offset {pos} does not decode "
                        f"({COMPRESSION.get(self.compression)}): {e}"
                    ) from e
                yield pos, raw[4 : 4 + fb_size]
                pos += 8 + n

    def iter_events(self) -> Iterator[RawEvents]:
        parts: list[np.ndarray] = []
        held = 0
        start = 0
        for pos, fb in self._packets(self.event_stream):
            try:
                table, ident = _root(fb)
                if ident != b"EVTS":
                    raise ValueError(f"identifier {ident!r}, expected b'EVTS'")
                first, n = table.vector(0)
                if first + 16 * n > len(fb):
                    raise ValueError(f"{n} events do not fit in {len(fb)} bytes")
            except (struct.error, ValueError) as e:
                raise ValueError(
                    f"{self.path}: corrupt event packet at byte offset {pos}: {e}"
                ) from e
            if n:
                parts.append(np.frombuffer(fb, dtype=EVENT_DTYPE, count=n, offset=first))
                held += n
            if held >= self.chunk_events:
                yield self._batch(parts, start)
                start += held
                parts, held = [], 0
        if held:
            yield self._batch(parts, start)

    @staticmethod
    def _batch(parts: list[np.ndarray], start: int) -> RawEvents:
        a = np.concatenate(parts)
        return RawEvents(a["t"].astype(np.int64), a["x"], a["y"], a["p"], start=start)

    def iter_frames(self) -> Iterator[Frame]:
        for pos, fb in self._packets(self.frame_stream):
            try:
                table, ident = _root(fb)
                if ident != b"FRME":
                    raise ValueError(f"identifier {ident!r}, expected b'FRME'")
                t = int(table.scalar(0, "q"))
                fmt = int(table.scalar(5, "b"))
                w, h = int(table.scalar(6, "h")), int(table.scalar(7, "h"))
                first, n = table.vector(10)
                ch = {0: 1, 16: 3, 24: 4}.get(fmt)
                if ch is None:
                    raise ValueError(f"unknown pixel format {fmt}")
                if n != w * h * ch or first + n > len(fb):
                    raise ValueError(f"{n} pixel bytes for a {w}x{h}x{ch} frame")
            except (struct.error, ValueError) as e:
                raise ValueError(
                    f"{self.path}: corrupt frame packet at byte offset {pos}: {e}"
                ) from e
            img = np.frombuffer(fb, dtype=np.uint8, count=n, offset=first).reshape(h, w, ch)
            if ch == 1:
                img = img[:, :, 0]
            else:
                img = img[:, :, 2::-1]  # BGR(A) -> RGB
            yield Frame(t, image=np.ascontiguousarray(img))


# --- the writer -----------------------------------------------------------------------------------
