"""``event_camera_msgs/EventPacket``: the event messages of today's ROS drivers.

The ROS drivers of current event cameras (``metavision_driver`` for Prophesee sensors,
``libcaer_driver`` for iniVation ones) publish packets of events in the sensor's own compact
encoding instead of one ROS structure per event::

    std_msgs/Header header
    uint32 height, uint32 width
    uint64 seq          # to detect lost packets
    uint64 time_base    # "mono": sensor time of the packet; "evt3": undefined
    string encoding     # "evt3", "mono" (deprecated), "trigger", "libcaer_cmp", ...
    bool is_bigendian
    uint8[] events

This module decodes the fixed fields from the serialised bytes of both ROS 1 (little-endian,
packed) and ROS 2 (CDR: a 4-byte encapsulation header, then fields aligned to their size), and
turns a sequence of packets into events:

- ``evt3``: the payloads are consecutive pieces of one Prophesee EVT 3.0 stream; they are decoded
  with the EVT 3.0 decoder of :mod:`evdense.io.prophesee`, its state carried across packets, so
  timestamps are the sensor's microseconds exactly as in a ``.raw`` file;
- ``mono``: 64-bit words, bit 63 polarity, bits 48-62 y, 32-47 x, 0-31 a time offset in
  nanoseconds from the packet's ``time_base`` (sensor time in nanoseconds);
- ``libcaer_cmp`` (``libcaer_driver``'s compressed DAVIS/DVXplorer packets): 16-bit little-endian
  words, the type in bits 15-12: 0 time high (bits 11-0, in units of 4096 us), 1 time low (bits
  11-0, us), 2 x address (bits 10-0), 3 y address (bits 10-0) and polarity (bit 11), which emits
  one event at the current x; 4 the base y (bits 10-0) and polarity (bit 11) of a vector;
  5 an 8-bit mask (bits 7-0) of events at rows ``base_y + i`` of the current column, after which
  the base y moves on by 8. Other types are skipped. Times restart at 0 in every packet and are
  offsets from its ``time_base`` (ns);
- ``libcaer`` (uncompressed): 8 bytes per event, a uint32 address word (bit 1 polarity,
  bits 2-16 y, bits 17-31 x) and an int32 time in us from ``time_base``, the 32-bit counter's
  wrap-arounds within a packet unrolled.

Events outside the packet's ``width`` x ``height`` are dropped (counted).

Other encodings raise ``ValueError`` naming them. Every length field is checked against the
bytes that are there before anything is sliced or allocated.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numba
import numpy as np

from evdense.io.base import event_buffers

EVENT_PACKET_TYPES = ("event_camera_msgs/msg/EventPacket",)
SUPPORTED_ENCODINGS = ("evt3", "mono", "libcaer_cmp", "libcaer")


@dataclass
class EventPacket:
    stamp_ns: int
    height: int
    width: int
    seq: int
    time_base: int
    encoding: str
    is_bigendian: bool
    events: memoryview


class _Cursor:
    def __init__(self, raw: bytes, start: int, cdr: bool) -> None:
        self.mv = memoryview(raw)
        self.off = start
        self.base = start  # CDR alignment counts from after the encapsulation header
        self.cdr = cdr

    def _align(self, n: int) -> None:
        if self.cdr:
            self.off += (-(self.off - self.base)) % n

    def take(self, fmt: str) -> int:
        size = struct.calcsize(fmt)
        self._align(size)
        if self.off + size > len(self.mv):
            raise ValueError(f"message ends at byte {len(self.mv)} inside a {size}-byte field")
        (v,) = struct.unpack_from("<" + fmt, self.mv, self.off)
        self.off += size
        return v

    def blob(self) -> memoryview:
        n = self.take("I")
        if n > len(self.mv) - self.off:
            raise ValueError(f"a field of {n} bytes at byte {self.off} runs past the message end")
        out = self.mv[self.off : self.off + n]
        self.off += n
        return out

    def string(self) -> str:
        b = bytes(self.blob())
        if self.cdr and b.endswith(b"\0"):
            b = b[:-1]
        return b.decode("utf-8", errors="replace")


def parse_event_packet(raw: bytes, ros2: bool) -> EventPacket:
    """The fields of one serialised EventPacket (ROS 1 or ROS 2 CDR); ``ValueError`` when malformed."""
    c, stamp = _header(raw, ros2)
    height, width = c.take("I"), c.take("I")
    seq, time_base = c.take("Q"), c.take("Q")
    encoding = c.string()
    big = bool(c.take("B"))
    events = c.blob()
    return EventPacket(stamp, height, width, seq, time_base, encoding, big, events)


@dataclass
class ImageMessage:
    stamp_ns: int
    height: int
    width: int
    encoding: str
    step: int
    data: memoryview


def _header(raw: bytes, ros2: bool) -> tuple[_Cursor, int]:
    if ros2:
        if len(raw) < 4 or raw[1] not in (0, 1):
            raise ValueError("not a CDR message (bad encapsulation header)")
        if raw[1] == 0:
            raise ValueError("big-endian CDR is not supported")
        c = _Cursor(raw, 4, cdr=True)
        sec, nsec = c.take("i"), c.take("I")
    else:
        c = _Cursor(raw, 0, cdr=False)
        c.take("I")  # header seq
        sec, nsec = c.take("I"), c.take("I")
    c.string()  # frame_id
    return c, sec * 1_000_000_000 + nsec


def parse_image(raw: bytes, ros2: bool) -> ImageMessage:
    """The fields of one serialised ``sensor_msgs/Image`` (ROS 1 or ROS 2 CDR), every length
    checked; tolerant of the empty CDR strings some recorders write (``rosbags`` refuses them)."""
    c, stamp = _header(raw, ros2)
    height, width = c.take("I"), c.take("I")
    encoding = c.string()
    c.take("B")  # is_bigendian (8-bit encodings only)
    step = c.take("I")
    return ImageMessage(stamp, height, width, encoding, step, c.blob())


class PacketDecoder:
    """Events of consecutive packets of one topic, state carried across packets."""

    def __init__(self, where: str) -> None:
        self.where = where
        self.encoding: str | None = None
        self._state = np.zeros(9, dtype=np.int64)
        self._carry = b""
        self.dropped_before_time_base = 0
        self.dropped_off_sensor = 0

    def decode(
        self, pkt: EventPacket, k: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t_us, x, y, p)`` of packet ``k`` (``ValueError`` naming it on a bad packet)."""
        enc = pkt.encoding.lower()
        if self.encoding is None:
            if enc not in SUPPORTED_ENCODINGS:
                raise ValueError(
                    f"{self.where}: packet {k}: encoding {pkt.encoding!r} is not supported "
                    f"(supported: {', '.join(SUPPORTED_ENCODINGS)})"
                )
            self.encoding = enc
        elif enc != self.encoding:
            raise ValueError(f"{self.where}: packet {k}: encoding changes from "
                             f"{self.encoding!r} to {pkt.encoding!r}")  # fmt: skip
        if pkt.is_bigendian:
            raise ValueError(f"{self.where}: packet {k}: big-endian payloads are not supported")
        if enc == "evt3":
            return self._evt3(bytes(pkt.events))
        if enc == "libcaer_cmp":
            return self._libcaer_cmp(pkt, k)
        if enc == "libcaer":
            return self._libcaer(pkt, k)
        return self._mono(pkt, k)

    def _whole(self, pkt: EventPacket, k: int, size: int, what: str) -> bytes:
        """The payload of packet ``k``, which must be a whole number of ``size``-byte ``what``."""
        if len(pkt.events) % size:
            raise ValueError(f"{self.where}: packet {k}: {len(pkt.events)} bytes is not a whole "
                             f"number of {what}")  # fmt: skip
        return pkt.events

    def _keep_on_sensor(self, pkt: EventPacket, t, x, y, p):
        ok = (x < pkt.width) & (y < pkt.height)
        if not ok.all():
            self.dropped_off_sensor += int((~ok).sum())
            t, x, y, p = t[ok], x[ok], y[ok], p[ok]
        return t, x, y, p

    def _libcaer_cmp(
        self, pkt: EventPacket, k: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        words = np.frombuffer(self._whole(pkt, k, 2, "16-bit libcaer_cmp words"), dtype="<u2")
        t_us, x, y, p = event_buffers(8 * len(words))
        n = _decode_libcaer_cmp(words, t_us, x, y, p)
        t = (int(pkt.time_base) + t_us[:n] * 1000 + 500) // 1000
        return self._keep_on_sensor(pkt, t, x[:n], y[:n], p[:n])

    def _libcaer(
        self, pkt: EventPacket, k: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        rec = np.frombuffer(
            self._whole(pkt, k, 8, "8-byte libcaer events"),
            dtype=np.dtype([("a", "<u4"), ("t", "<i4")]),
        )
        a = rec["a"]
        ts = rec["t"].astype(np.int64)
        wraps = np.concatenate([[0], np.cumsum(np.diff(ts) < 0)]) if len(ts) else ts
        t = (int(pkt.time_base) + (ts + wraps * (1 << 31)) * 1000 + 500) // 1000
        x = ((a >> 17) & 0x7FFF).astype(np.uint16)
        y = ((a >> 2) & 0x7FFF).astype(np.uint16)
        p = ((a >> 1) & 1).astype(np.uint8)
        return self._keep_on_sensor(pkt, t.astype(np.int64), x, y, p)

    def _evt3(self, payload: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        from evdense.io.prophesee import _decode_evt3

        data = self._carry + payload
        nw = len(data) // 2
        self._carry = data[2 * nw :]
        words = np.frombuffer(data, dtype="<u2", count=nw)
        t, x, y, p = event_buffers(12 * nw)
        n = _decode_evt3(words, self._state, t, x, y, p)
        self.dropped_before_time_base = int(self._state[8])
        return t[:n], x[:n], y[:n], p[:n]

    def _mono(
        self, pkt: EventPacket, k: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        w = np.frombuffer(self._whole(pkt, k, 8, "64-bit mono events"), dtype="<u8")
        dt = (w & np.uint64(0xFFFFFFFF)).astype(np.int64)
        x = ((w >> np.uint64(32)) & np.uint64(0xFFFF)).astype(np.uint16)
        y = ((w >> np.uint64(48)) & np.uint64(0x7FFF)).astype(np.uint16)
        p = (w >> np.uint64(63)).astype(np.uint8)
        t = (int(pkt.time_base) + dt + 500) // 1000
        return t.astype(np.int64), x, y, p


@numba.njit(cache=True, nogil=True)
def _decode_libcaer_cmp(words, t, x, y, p):  # pragma: no cover - compiled
    n = 0
    th = 0
    tl = 0
    cx = 0
    base_y = 0
    vpol = 0
    for i in range(words.shape[0]):
        w = np.int64(words[i])
        kind = w >> 12
        if kind == 0:
            th = w & 0xFFF
        elif kind == 1:
            tl = w & 0xFFF
        elif kind == 2:
            cx = w & 0x7FF
        elif kind == 3:
            t[n] = (th << 12) | tl
            x[n] = cx
            y[n] = w & 0x7FF
            p[n] = (w >> 11) & 1
            n += 1
        elif kind == 4:
            base_y = w & 0x7FF
            vpol = (w >> 11) & 1
        elif kind == 5:
            for b in range(8):
                if (w >> b) & 1:
                    t[n] = (th << 12) | tl
                    x[n] = cx
                    y[n] = base_y + b
                    p[n] = vpol
                    n += 1
            base_y += 8
    return n
