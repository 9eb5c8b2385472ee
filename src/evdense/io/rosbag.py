"""ROS bags, read with the ``rosbags`` package, without ROS.

Events: ``event_camera_msgs/EventPacket`` (today's ``metavision_driver`` and ``libcaer_driver``;
:mod:`evdense.io.event_packets`) in ROS 1 bags and ROS 2 bags (a folder with ``metadata.yaml``
and ``.mcap`` or sqlite3 ``.db3`` storage, or such a storage file alone), and the older
``dvs_msgs/EventArray`` (rpg_dvs_ros; also ``prophesee_event_msgs/EventArray``) in ROS 1 bags.

Events are decoded straight from the ROS1 serialisation (header, uint32 height, uint32 width,
uint32 count, then 13-byte events ``uint16 x, uint16 y, uint32 secs, uint32 nsecs, uint8 polarity``)
with NumPy, which is much faster than building one Python object per event. Timestamps become
``secs * 1e6 + round(nsecs / 1000)`` microseconds. The bag may also hold ``sensor_msgs/Image``
frames (conventional frames), ``sensor_msgs/CameraInfo`` (intrinsics) and
``geometry_msgs/PoseStamped`` (ground-truth trajectory); each is used when exactly one topic of
that type exists, or the topic named in the reader's arguments.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from evdense.camera import Camera
from evdense.io.base import DEFAULT_CHUNK_EVENTS, Frame, RawEvents, Recording, Trajectory
from evdense.io.event_packets import (
    EVENT_PACKET_TYPES,
    PacketDecoder,
    parse_event_packet,
    parse_image,
)
from evdense.log import get_logger

log = get_logger("io")

EVENT_MSG = "uint16 x\nuint16 y\ntime ts\nbool polarity\n"
EVENT_ARRAY_MSG = "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n"
EVENT_ARRAY_TYPES = ("dvs_msgs/msg/EventArray", "prophesee_event_msgs/msg/EventArray")
ROS_EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("s", "<u4"), ("ns", "<u4"), ("p", "u1")])


def dvs_typestore():
    """A ROS1 typestore that also knows ``dvs_msgs/msg/Event`` and ``dvs_msgs/msg/EventArray``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    types = {}
    types.update(get_types_from_msg(EVENT_MSG, "dvs_msgs/msg/Event"))
    types.update(get_types_from_msg(EVENT_ARRAY_MSG, "dvs_msgs/msg/EventArray"))
    ts.register(types)
    return ts


MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
MAX_CHUNK_BYTES = 256 << 20
"""Largest uncompressed chunk accepted in a ROS 1 bag (rosbag's default chunks are 768 KiB)."""


def is_ros2_bag(path: Path) -> bool:
    """A ROS 2 bag folder (``metadata.yaml``) or storage file (``.mcap``, ``.db3``)."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    with open(path, "rb") as f:
        head = f.read(16)
    return head.startswith(MCAP_MAGIC) or head.startswith(SQLITE_MAGIC)


def _open_ros2(path: Path):
    """A rosbags reader over a ROS 2 bag. A folder whose ``metadata.yaml`` leaves the storage
    plugin empty (as some recorders write it) is read through its single storage file."""
    from rosbags.rosbag2 import Reader, ReaderError

    target = path
    if path.is_dir() or path.suffix.lower() == ".mcap":
        for mcap in [path] if path.is_file() else sorted(path.glob("*.mcap")):
            check_mcap_records(mcap)
    if path.is_dir():
        import yaml

        try:
            meta = yaml.safe_load((path / "metadata.yaml").read_text())[
                "rosbag2_bagfile_information"
            ]
            files = [Path(str(f)).name for f in meta["relative_file_paths"]]
            storage = meta.get("storage_identifier") or ""
        except (OSError, KeyError, TypeError, yaml.YAMLError) as e:
            raise ValueError(f"{path / 'metadata.yaml'}: not a ROS 2 bag's metadata ({e})") from e
        if not storage:
            if len(files) != 1:
                raise ValueError(f"{path / 'metadata.yaml'}: no storage plugin named and "
                                 f"{len(files)} storage files")  # fmt: skip
            target = path / files[0]  # a file name only: it stays inside the bag's folder
    try:
        reader = Reader(target)
        reader.open()
    except (ReaderError, FileNotFoundError) as e:
        raise ValueError(f"{path}: not a readable ROS 2 bag ({e})") from e
    return reader


def check_rosbag1_records(path: Path) -> None:
    """Walk the top-level records of a ROS 1 bag and check every length against the file, and every
    chunk's stated uncompressed size against :data:`MAX_CHUNK_BYTES`, before ``rosbags`` reads
    (and allocates from) them. ``ValueError`` naming the byte offset otherwise."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        if f.read(13) != b"#ROSBAG V2.0\n":
            raise ValueError(f"{path}: not a ROS 1 (V2.0) bag")
        pos = 13
        while pos < size:
            f.seek(pos)
            head = f.read(4)
            if len(head) < 4:
                raise ValueError(f"{path}: truncated record header at byte offset {pos}")
            (hlen,) = struct.unpack("<I", head)
            if pos + 8 + hlen > size:
                raise ValueError(f"{path}: record at byte offset {pos} claims a {hlen}-byte header, "
                                 "beyond the end of the file")  # fmt: skip
            header = f.read(hlen)
            fields, i = {}, 0
            while i + 4 <= hlen:
                (flen,) = struct.unpack_from("<I", header, i)
                if i + 4 + flen > hlen:
                    raise ValueError(f"{path}: malformed record header at byte offset {pos}")
                name, _, value = header[i + 4 : i + 4 + flen].partition(b"=")
                fields[name] = value
                i += 4 + flen
            (dlen,) = struct.unpack("<I", f.read(4))
            if pos + 8 + hlen + dlen > size:
                raise ValueError(f"{path}: record at byte offset {pos} claims {dlen} data bytes, "
                                 "beyond the end of the file")  # fmt: skip
            if fields.get(b"op") == b"\x05" and len(fields.get(b"size", b"")) == 4:
                (usize,) = struct.unpack("<I", fields[b"size"])
                if usize > MAX_CHUNK_BYTES:
                    raise ValueError(f"{path}: chunk at byte offset {pos} says it unpacks to "
                                     f"{usize} bytes (limit {MAX_CHUNK_BYTES})")  # fmt: skip
            pos += 8 + hlen + dlen


def check_mcap_records(path: Path) -> None:
    """Walk the records of an MCAP file and check what ``rosbags`` would allocate or seek from
    before it does: every record's length against the file, every chunk's stated uncompressed
    size against :data:`MAX_CHUNK_BYTES`, and the footer's and chunk indexes' offsets against the
    records actually there. ``ValueError`` naming the byte offset otherwise."""
    size = path.stat().st_size
    starts: dict[int, tuple[int, int]] = {}  # offset -> (opcode, total length)
    footer: bytes | None = None
    chunk_indexes: list[tuple[int, int, int]] = []
    with open(path, "rb") as f:
        if f.read(8) != MCAP_MAGIC:
            raise ValueError(f"{path}: not an MCAP file (bad magic)")
        pos = 8
        while pos < size:
            f.seek(pos)
            head = f.read(9)
            if len(head) < 9:
                if pos + 8 == size and head[:8] == MCAP_MAGIC[:8][: len(head)]:
                    break
                raise ValueError(f"{path}: truncated MCAP record at byte offset {pos}")
            if head[:8] == MCAP_MAGIC and pos + 8 == size:
                break
            op, n = head[0], struct.unpack_from("<Q", head, 1)[0]
            if pos + 9 + n > size:
                raise ValueError(f"{path}: MCAP record at byte offset {pos} claims {n} bytes, "
                                 "beyond the end of the file")  # fmt: skip
            starts[pos] = (op, 9 + n)
            if op == 0x06:  # chunk: start, end, uncompressed size, ...
                if n < 24:
                    raise ValueError(f"{path}: MCAP chunk at byte offset {pos} is too short")
                (usize,) = struct.unpack("<Q", f.read(24)[16:24])
                if usize > MAX_CHUNK_BYTES:
                    raise ValueError(f"{path}: MCAP chunk at byte offset {pos} says it unpacks "
                                     f"to {usize} bytes (limit {MAX_CHUNK_BYTES})")  # fmt: skip
            elif op == 0x08 and n >= 32:  # chunk index: start, end, chunk offset, chunk length
                b = f.read(32)
                chunk_indexes.append((pos, *struct.unpack_from("<QQ", b, 16)))
            elif op == 0x02 and n >= 16:  # footer: summary start, summary offset start
                footer = f.read(16)
            pos += 9 + n
    for at, off, length in chunk_indexes:
        if starts.get(off, (None, None)) != (0x06, length):
            raise ValueError(f"{path}: MCAP chunk index at byte offset {at} points at byte {off}, "
                             "where no chunk of that length starts")  # fmt: skip
    if footer is not None:
        for off in struct.unpack("<QQ", footer):
            if off and off not in starts:
                raise ValueError(
                    f"{path}: MCAP footer points at byte {off}, where no record starts"
                )


def decode_event_array(raw: bytes) -> tuple[int, int, np.ndarray]:
    """``(width, height, events)`` from one serialised EventArray; events has fields x, y, s, ns, p."""
    mv = memoryview(raw)
    off = 12  # seq, stamp.secs, stamp.nsecs
    (flen,) = np.frombuffer(mv, "<u4", 1, off)
    off += 4 + int(flen)
    h, w, n = (int(v) for v in np.frombuffer(mv, "<u4", 3, off))
    off += 12
    if off + 13 * n > len(raw):
        raise ValueError(f"message holds {len(raw) - off} bytes for {n} events")
    return w, h, np.frombuffer(mv, ROS_EVENT_DTYPE, n, off)


class RosbagRecording(Recording):
    """A ROS 1 or ROS 2 bag; ``topic`` selects the event topic when there are several."""

    format = "rosbag"

    def __init__(
        self,
        path: str | Path,
        chunk_events: int = DEFAULT_CHUNK_EVENTS,
        topic: str | None = None,
        image_topic: str | None = None,
        pose_topic: str | None = None,
    ) -> None:
        super().__init__(path, chunk_events)
        self.ros2 = is_ros2_bag(self.path)
        if self.ros2:
            from rosbags.rosbag2 import ReaderError

            self._ReaderError = ReaderError
            self._reader = _open_ros2(self.path)
        else:
            from rosbags.rosbag1 import Reader, ReaderError

            self._ReaderError = ReaderError
            check_rosbag1_records(self.path)
            try:
                self._reader = Reader(self.path)
                self._reader.open()
            except ReaderError as e:
                raise ValueError(f"{self.path}: not a readable ROS1 bag ({e})") from e
        conns = self._reader.connections
        self.topics = {c.topic: c.msgtype for c in conns}
        types = EVENT_PACKET_TYPES if self.ros2 else EVENT_ARRAY_TYPES + EVENT_PACKET_TYPES
        self._ev = self._select(conns, types, topic, "event", required=True)
        self._packets = self._ev[0].msgtype in EVENT_PACKET_TYPES
        self._img = self._select(conns, ("sensor_msgs/msg/Image",), image_topic, "image")
        self._info = self._select(conns, ("sensor_msgs/msg/CameraInfo",), None, "camera info")
        self._pose = self._select(conns, ("geometry_msgs/msg/PoseStamped",), pose_topic, "pose")
        self.metadata["topics"] = self.topics
        self.metadata["event_topic"] = self._ev[0].topic
        self.metadata["event_message"] = self._ev[0].msgtype
        # sensor size from the first event message
        for _, _, raw in self._reader.messages(connections=self._ev):
            if self._packets:
                pkt = parse_event_packet(raw, self.ros2)
                w, h = pkt.width, pkt.height
                self.metadata["encoding"] = pkt.encoding
            else:
                w, h, _ = decode_event_array(raw)
            if w and h:
                self.width, self.height = w, h
            break
        self._typestore = None

    def _select(self, conns, types, topic, what: str, required: bool = False):
        cands = [c for c in conns if c.msgtype in types]
        if topic is not None:
            cands = [c for c in cands if c.topic == topic]
            if not cands:
                raise ValueError(f"{self.path}: no {what} topic {topic!r} (topics: {self.topics})")
        names = sorted({c.topic for c in cands})
        if not names:
            if required:
                raise ValueError(f"{self.path}: no {'/'.join(types)} topic (topics: {self.topics})")
            return []
        if len(names) > 1:
            if required:
                raise ValueError(
                    f"{self.path}: several {what} topics {names}; name one (dataset key `topic`)"
                )
            log.warning(
                "%s: several %s topics %s; using none (name one to use it)", self.path, what, names
            )
            return []
        return [c for c in cands if c.topic == names[0]]

    def close(self) -> None:
        self._reader.close()

    def _ts(self):
        if self._typestore is None:
            if self.ros2:
                from rosbags.typesys import Stores, get_typestore

                self._typestore = get_typestore(Stores.ROS2_HUMBLE)
            else:
                self._typestore = dvs_typestore()
        return self._typestore

    def _deserialize(self, raw: bytes, msgtype: str):
        if self.ros2:
            return self._ts().deserialize_cdr(raw, msgtype)
        return self._ts().deserialize_ros1(raw, msgtype)

    def iter_events(self) -> Iterator[RawEvents]:
        if self._packets:
            yield from self._iter_packets()
            return
        parts: list[np.ndarray] = []
        held = start = 0
        k = 0
        try:
            for _, _, raw in self._reader.messages(connections=self._ev):
                try:
                    _, _, ev = decode_event_array(raw)
                except (ValueError, IndexError) as e:
                    raise ValueError(
                        f"{self.path}: EventArray message {k} on {self._ev[0].topic} is corrupt: {e}"
                    ) from e
                k += 1
                if len(ev):
                    parts.append(ev)
                    held += len(ev)
                if held >= self.chunk_events:
                    yield self._batch(parts, start)
                    start += held
                    parts, held = [], 0
        except self._ReaderError as e:
            raise ValueError(
                f"{self.path}: bag is corrupt after message {k} on {self._ev[0].topic}: {e}"
            ) from e
        if held:
            yield self._batch(parts, start)

    def _iter_packets(self) -> Iterator[RawEvents]:
        topic = self._ev[0].topic
        dec = PacketDecoder(f"{self.path}: {topic}")
        cols: list[tuple[np.ndarray, ...]] = []
        held = start = k = 0
        last_seq = None
        lost = 0
        try:
            for _, _, raw in self._reader.messages(connections=self._ev):
                try:
                    pkt = parse_event_packet(raw, self.ros2)
                except ValueError as e:
                    raise ValueError(
                        f"{self.path}: EventPacket {k} on {topic} is corrupt: {e}"
                    ) from e
                if last_seq is not None and pkt.seq > last_seq + 1:
                    lost += pkt.seq - last_seq - 1
                last_seq = pkt.seq
                t, x, y, p = dec.decode(pkt, k)
                k += 1
                if len(t):
                    cols.append((t, x, y, p))
                    held += len(t)
                if held >= self.chunk_events:
                    yield self._packet_batch(cols, start, k)
                    start += held
                    cols, held = [], 0
        except self._ReaderError as e:
            raise ValueError(f"{self.path}: bag is corrupt after packet {k} on {topic}: {e}") from e
        if held:
            yield self._packet_batch(cols, start, k)
        if lost:
            log.warning(
                "%s: %d EventPackets missing on %s (gaps in their seq)", self.path, lost, topic
            )
        self.metadata["lost_packets"] = int(lost)
        self.metadata["dropped_before_time_base"] = dec.dropped_before_time_base
        self.metadata["dropped_off_sensor"] = dec.dropped_off_sensor

    @staticmethod
    def _packet_batch(cols: list[tuple[np.ndarray, ...]], start: int, k: int) -> RawEvents:
        t, x, y, p = (np.concatenate([c[i] for c in cols]) for i in range(4))
        return RawEvents(t, x, y, p, start=start,
                         locate=lambda i, k=k: f"in the EventPackets before packet {k}")  # fmt: skip

    @staticmethod
    def _batch(parts: list[np.ndarray], start: int) -> RawEvents:
        a = np.concatenate(parts)
        t = a["s"].astype(np.int64) * 1_000_000 + (a["ns"].astype(np.int64) + 500) // 1000
        return RawEvents(t, a["x"], a["y"], a["p"], start=start)

    def iter_frames(self) -> Iterator[Frame]:
        if not self._img:  # rosbags reads every message when given no connection
            return
        for k, (_, _, raw) in enumerate(self._reader.messages(connections=self._img)):
            try:
                m = parse_image(raw, self.ros2)
            except ValueError as e:
                raise ValueError(f"{self.path}: Image message {k} on {self._img[0].topic} is "
                                 f"corrupt: {e}") from e  # fmt: skip
            t_us = m.stamp_ns // 1000 + (1 if m.stamp_ns % 1000 >= 500 else 0)
            data = np.frombuffer(m.data, dtype=np.uint8)
            if m.step < m.width or len(data) < m.height * m.step:
                raise ValueError(f"{self.path}: Image message {k}: {len(data)} bytes for "
                                 f"{m.height} rows of {m.step}")  # fmt: skip
            data = data[: m.height * m.step]
            enc = m.encoding.lower()
            ch = {
                "mono8": 1,
                "8uc1": 1,
                "rgb8": 3,
                "bgr8": 3,
                "8uc3": 3,
                "rgba8": 4,
                "bgra8": 4,
            }.get(enc)
            if ch is None:
                raise ValueError(
                    f"{self.path}: image encoding {m.encoding!r} is not supported (8-bit only)"
                )
            if m.step < m.width * ch:
                raise ValueError(f"{self.path}: Image message {k}: row of {m.step} bytes for "
                                 f"{m.width} pixels of {m.encoding}")  # fmt: skip
            img = data.reshape(m.height, m.step)[:, : m.width * ch].reshape(m.height, m.width, ch)
            if enc.startswith("bgr"):
                img = img[:, :, 2::-1]
            elif ch == 4:
                img = img[:, :, :3]
            yield Frame(t_us, image=np.ascontiguousarray(img[:, :, 0] if ch == 1 else img))

    def camera(self, width: int, height: int) -> Camera | None:
        if not self._info:
            return None
        for _, _, raw in self._reader.messages(connections=self._info):
            m = self._deserialize(raw, "sensor_msgs/msg/CameraInfo")
            K = np.asarray(m.K if hasattr(m, "K") else m.k, dtype=np.float64)
            D = list(np.asarray(m.D if hasattr(m, "D") else m.d, dtype=np.float64))
            if not K.any():
                return None
            model = m.distortion_model.lower()
            if D and model not in ("plumb_bob", "radtan", "rational_polynomial"):
                log.warning(
                    "%s: distortion model %r not supported; ignoring the camera info",
                    self.path,
                    model,
                )
                return None
            dist = tuple(float(v) for v in (D[:4] + [0.0] * 4)[:4])
            w, h = int(m.width) or width, int(m.height) or height
            return Camera(w, h, float(K[0]), float(K[4]), float(K[2]), float(K[5]), dist)  # type: ignore[arg-type]
        return None

    def trajectory(self) -> Trajectory | None:
        if not self._pose:
            return None
        from evdense.poses import tum_to_poses

        ts, rows = [], []
        for _, _, raw in self._reader.messages(connections=self._pose):
            m = self._deserialize(raw, "geometry_msgs/msg/PoseStamped")
            ts.append(int(m.header.stamp.sec) + int(m.header.stamp.nanosec) * 1e-9)
            q, pp = m.pose.orientation, m.pose.position
            rows.append([pp.x, pp.y, pp.z, q.x, q.y, q.z, q.w])
        if not ts:
            return None
        return Trajectory(
            np.asarray(ts),
            tum_to_poses(np.asarray(rows)),
            source=f"{self.path}:{self._pose[0].topic}",
        )
