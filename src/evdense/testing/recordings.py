"""Writers of the recording formats our readers take (AEDAT4, E2VID HDF5, NumPy, Prophesee
DAT/EVT2/EVT3, ROS 1 and ROS 2 bags, RPG text): test and benchmark fixtures, so that every reader is tested
on files made from known events (the pipeline itself never writes these formats)."""

from __future__ import annotations

import struct
from pathlib import Path

import h5py
import numpy as np

from evdense.camera import Camera
from evdense.io.aedat4 import EVENT_DTYPE, MAGIC
from evdense.io.rosbag import ROS_EVENT_DTYPE, dvs_typestore


def write_aedat4(
    path: str | Path,
    t_us: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    width: int,
    height: int,
    frames: list[tuple[int, np.ndarray]] | None = None,
    compression: int = 1,
    packet_events: int = 4096,
) -> Path:
    """Write an AEDAT 4.0 file: events in packets of ``packet_events`` on stream 0, optional frames
    (``(t_us, uint8 (H, W) or (H, W, 3) RGB)``) on stream 1, compression 0 (none), 1 (LZ4) or 3 (ZSTD).
    No data table is written (dataTablePosition -1), which readers must accept.
    """
    compress = {0: lambda b: b}.get(compression)
    if compress is None:
        if compression in (1, 2):
            import lz4.frame

            compress = lz4.frame.compress
        else:
            try:
                from backports import zstd  # type: ignore[import-not-found]
            except ImportError:
                import zstandard as zstd  # type: ignore[no-redef]
            compress = zstd.compress
    header = _build_table(
        b"IOHE",
        [(0, "i", compression), (1, "q", -1), (2, "str", _info_xml(width, height, bool(frames)))],
    )
    ev = np.zeros(len(t_us), dtype=EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = t_us, x, y, np.asarray(p) > 0
    packets: list[tuple[int, int, bytes]] = []  # (time, stream, payload)
    for s in range(0, len(ev), packet_events):
        chunk = ev[s : s + packet_events]
        fb = _build_table(b"EVTS", [(0, "bytes", (chunk.tobytes(), len(chunk), 8))])
        packets.append((int(chunk["t"][0]), 0, fb))
    for ft, img in frames or []:
        img = np.asarray(img, dtype=np.uint8)
        fmt, pix = (0, img) if img.ndim == 2 else (16, img[:, :, ::-1])
        fb = _build_table(
            b"FRME",
            [
                (0, "q", int(ft)),
                (1, "q", int(ft)),
                (2, "q", int(ft)),
                (5, "b", fmt),
                (6, "h", img.shape[1]),
                (7, "h", img.shape[0]),
                (10, "bytes", (np.ascontiguousarray(pix).tobytes(), pix.size, 1)),
            ],
        )
        packets.append((int(ft), 1, fb))
    packets.sort(key=lambda q: q[0])
    with open(path, "wb") as f:
        f.write(MAGIC + b"\r\n")
        f.write(header)  # already size-prefixed
        for _, sid, fb in packets:
            data = compress(fb)
            f.write(struct.pack("<ii", sid, len(data)))
            f.write(data)
    return Path(path)


def _build_table(ident: bytes, fields: list[tuple[int, str, object]]) -> bytes:
    """A size-prefixed flatbuffer holding one root table.

    ``fields``: ``(slot, kind, value)`` with kind a struct format ("q", "i", "h", "b") for scalars,
    "bytes" for a vector (value = ``(raw bytes, element count, element alignment)``) or "str".
    """
    nslots = max(s for s, _, _ in fields) + 1
    out = bytearray(12)  # size prefix, root offset, identifier
    out[8:12] = ident
    vt_pos = len(out)
    out += bytes(4 + 2 * nslots)
    while len(out) % 8:
        out += b"\0"
    table = len(out)
    out += struct.pack("<i", table - vt_pos)
    slots = {}
    refs = []
    for slot, kind, value in sorted(
        fields, key=lambda f: -struct.calcsize(f[1]) if f[1] not in ("bytes", "str") else -4
    ):
        size = 4 if kind in ("bytes", "str") else struct.calcsize(kind)
        while len(out) % size:
            out += b"\0"
        slots[slot] = len(out) - table
        if kind in ("bytes", "str"):
            refs.append((len(out), kind, value))
            out += bytes(4)
        else:
            out += struct.pack("<" + kind, value)
    table_size = len(out) - table
    for at, kind, value in refs:
        if kind == "str":
            data, n, align = str(value).encode() + b"\0", len(str(value).encode()), 4
        else:
            data, n, align = value  # type: ignore[misc]
        while (len(out) + 4) % max(align, 4):
            out += b"\0"
        struct.pack_into("<I", out, at, len(out) - at)
        out += struct.pack("<I", n) + data
    while len(out) % 4:
        out += b"\0"
    struct.pack_into("<HH", out, vt_pos, 4 + 2 * nslots, table_size)
    for slot, off in slots.items():
        struct.pack_into("<H", out, vt_pos + 4 + 2 * slot, off)
    struct.pack_into("<I", out, 4, table - 4)
    struct.pack_into("<I", out, 0, len(out) - 4)
    return bytes(out)


def _info_xml(width: int, height: int, with_frames: bool) -> str:
    def node(i: int, typ: str, name: str) -> str:
        return (
            f'<node name="{i}" path="/mainloop/Recorder/outInfo/{i}/">'
            f'<attr key="compression" type="string">LZ4</attr>'
            f'<attr key="originalOutputName" type="string">{name}</attr>'
            f'<attr key="typeIdentifier" type="string">{typ}</attr>'
            f'<node name="info" path="/mainloop/Recorder/outInfo/{i}/info/">'
            f'<attr key="sizeX" type="int">{width}</attr><attr key="sizeY" type="int">{height}</attr>'
            f"</node></node>"
        )

    body = node(0, "EVTS", "events") + (node(1, "FRME", "frames") if with_frames else "")
    return f'<dv version="2.0"><node name="outInfo" path="/mainloop/Recorder/outInfo/">{body}</node></dv>'


def write_e2vid_h5(
    path: str | Path,
    t_us: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    width: int,
    height: int,
    ts_seconds: bool = True,
    frames: list[tuple[int, np.ndarray]] | None = None,
) -> Path:
    """Write an E2VID-style HDF5 (``ts`` float64 seconds or int64 us, ``ps`` bool as the tools do).

    ``frames``: optional ``(t_us, image uint8 (H, W))`` pairs stored as ``images/imageNNNNNNNNN``.
    """
    path = Path(path)
    t_us = np.asarray(t_us, dtype=np.int64)
    with h5py.File(path, "w") as f:
        f.create_dataset("events/xs", data=np.asarray(x, dtype=np.int16))
        f.create_dataset("events/ys", data=np.asarray(y, dtype=np.int16))
        f.create_dataset("events/ts", data=t_us * 1e-6 if ts_seconds else t_us)
        f.create_dataset("events/ps", data=np.asarray(p) > 0)
        f.attrs["sensor_resolution"] = (height, width)
        f.attrs["num_events"] = len(t_us)
        for k, (ft, img) in enumerate(frames or []):
            d = f.create_dataset(f"images/image{k:09d}", data=img)
            d.attrs["timestamp"] = ft * 1e-6
            d.attrs["size"] = img.shape
    return path


def write_npy(
    path: str | Path, t_us: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray
) -> Path:
    """Write a structured ``.npy`` with fields ``t`` (int64 us), ``x``, ``y`` (uint16), ``p`` (int8)."""
    dt = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    a = np.empty(len(t_us), dtype=dt)
    a["t"], a["x"], a["y"], a["p"] = t_us, x, y, p
    np.save(path, a)
    return Path(path)


def write_npz(
    path: str | Path,
    t_us: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    width: int | None = None,
    height: int | None = None,
    compressed: bool = False,
) -> Path:
    """Write ``t`` (int64 us), ``x``, ``y`` (uint16), ``p`` (int8) and optional ``width``/``height`` to ``.npz``."""
    arrays = {
        "t": np.asarray(t_us, dtype=np.int64),
        "x": np.asarray(x, dtype=np.uint16),
        "y": np.asarray(y, dtype=np.uint16),
        "p": np.asarray(p, dtype=np.int8),
    }
    if width is not None and height is not None:
        arrays |= {"width": np.int64(width), "height": np.int64(height)}
    (np.savez_compressed if compressed else np.savez)(path, **arrays)
    return Path(path)


def write_evt3(
    path: str | Path, t_us, x, y, p, width: int, height: int, vectorize: bool = True
) -> Path:
    """Write an EVT 3.0 ``.raw`` file (:func:`encode_evt3` after the Prophesee header)."""
    with open(path, "wb") as f:
        f.write(
            _header_text(
                [
                    "camera_integrator_name Prophesee",
                    "evt 3.0",
                    f"format EVT3;height={height};width={width}",
                    f"geometry {width}x{height}",
                    "end",
                ]
            )
        )
        f.write(encode_evt3(t_us, x, y, p, vectorize).tobytes())
    return Path(path)


def encode_evt3(t_us, x, y, p, vectorize: bool = True) -> np.ndarray:
    """Events as EVT 3.0 words (``<u2``). With ``vectorize``, runs of events with the same time, row
    and polarity and increasing x within 12 pixels become VECT_BASE_X + VECT_12 words (as cameras do).

    A plain Python loop: meant for tests and small streams.
    """
    t_us = np.asarray(t_us, dtype=np.int64)
    x = np.asarray(x, dtype=np.int64)
    y = np.asarray(y, dtype=np.int64)
    pol = (np.asarray(p) > 0).astype(np.int64)
    out: list[int] = []
    cur_th = cur_tl = cur_y = None
    n = len(t_us)
    i = 0
    while i < n:
        t = int(t_us[i])
        th_abs, tl = t >> 12, t & 0xFFF
        if cur_th is None or th_abs != cur_th:
            # keep consecutive TIME_HIGH steps below half the 12-bit range so wraps are detectable
            while cur_th is not None and th_abs - cur_th > 1024:
                cur_th += 1024
                out.append((0x8 << 12) | (cur_th & 0xFFF))
            out.append((0x8 << 12) | (th_abs & 0xFFF))
            cur_th = th_abs
            cur_tl = None
        if tl != cur_tl:
            out.append((0x6 << 12) | tl)
            cur_tl = tl
        if y[i] != cur_y:
            out.append(int(y[i]))
            cur_y = int(y[i])
        j = i + 1
        if vectorize:
            while (
                j < n
                and j - i < 12
                and t_us[j] == t
                and y[j] == y[i]
                and pol[j] == pol[i]
                and x[i] < x[j] < x[i] + 12
                and x[j] > x[j - 1]
            ):
                j += 1
        if j - i >= 2:
            out.append((0x3 << 12) | (int(pol[i]) << 11) | int(x[i]))
            mask = 0
            for k in range(i, j):
                mask |= 1 << int(x[k] - x[i])
            out.append((0x4 << 12) | mask)
        else:
            out.append((0x2 << 12) | (int(pol[i]) << 11) | int(x[i]))
        i = j
    return np.asarray(out, dtype="<u2")


def write_evt2(path: str | Path, t_us, x, y, p, width: int, height: int) -> Path:
    """Write an EVT 2.0 ``.raw`` file (a TIME_HIGH word whenever ``t >> 6`` changes)."""
    t_us = np.asarray(t_us, dtype=np.int64)
    th = t_us >> 6
    new = np.ones(len(t_us), dtype=bool)
    new[1:] = th[1:] != th[:-1]
    pol = (np.asarray(p) > 0).astype(np.uint32)
    cd = (
        (pol << 28)
        | ((t_us & 0x3F).astype(np.uint32) << 22)
        | (np.asarray(x, np.uint32) << 11)
        | np.asarray(y, np.uint32)
    )
    words = np.empty(len(t_us) + int(new.sum()), dtype="<u4")
    pos = np.arange(len(t_us)) + np.cumsum(new)  # where each CD word goes
    words[pos] = cd
    words[pos[new] - 1] = (0x8 << 28) | (th[new] & 0x0FFFFFFF).astype(np.uint32)
    with open(path, "wb") as f:
        f.write(
            _header_text(
                [
                    "camera_integrator_name Prophesee",
                    "evt 2.0",
                    f"format EVT2;height={height};width={width}",
                    f"geometry {width}x{height}",
                    "end",
                ]
            )
        )
        f.write(words.tobytes())
    return Path(path)


def write_dat(path: str | Path, t_us, x, y, p, width: int, height: int) -> Path:
    """Write a ``.dat`` CD file (``t_us`` < 2**32, ``p`` 0/1 or -1/+1)."""
    t_us = np.asarray(t_us, dtype=np.int64)
    if len(t_us) and (t_us.min() < 0 or t_us.max() >= 1 << 32):
        raise ValueError(f"{path}: DAT timestamps must fit in 32 bits of microseconds")
    rec = np.empty((len(t_us), 2), dtype="<u4")
    rec[:, 0] = t_us
    pol = (np.asarray(p) > 0).astype(np.uint32)
    rec[:, 1] = np.asarray(x, np.uint32) | (np.asarray(y, np.uint32) << 14) | (pol << 28)
    with open(path, "wb") as f:
        f.write(
            _header_text(
                [
                    "Data file containing CD events",
                    "Version 2",
                    f"Width {width}",
                    f"Height {height}",
                ]
            )
        )
        f.write(bytes([12, 8]))
        f.write(rec.tobytes())
    return Path(path)


def _header_text(lines: list[str]) -> bytes:
    return "".join(f"% {s}\n" for s in lines).encode()


def write_rosbag1(
    path: str | Path,
    t_us: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    width: int,
    height: int,
    topic: str = "/dvs/events",
    events_per_message: int = 5000,
    frames: list[tuple[int, np.ndarray]] | None = None,
    camera: Camera | None = None,
    poses: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """Write a ROS1 bag with ``dvs_msgs/EventArray`` messages (as rpg_dvs_ros records them).

    Optional side data as the ECD bags hold it: ``frames`` (``(t_us, uint8 (H, W) or (H, W, 3) RGB)``)
    on ``/dvs/image_raw``, ``camera`` on ``/dvs/camera_info``, ``poses`` (``t`` seconds ``(N,)``,
    ``T_wc`` ``(N, 4, 4)``) on ``/optitrack/davis``.
    """
    from rosbags.rosbag1 import Writer

    ts = dvs_typestore()
    msgdef, md5 = ts.generate_msgdef("dvs_msgs/msg/EventArray")
    path = Path(path)
    path.unlink(missing_ok=True)
    t_us = np.asarray(t_us, dtype=np.int64)
    with Writer(path) as w:
        conn = w.add_connection(topic, "dvs_msgs/msg/EventArray", msgdef=msgdef, md5sum=md5)
        for seq, s in enumerate(range(0, len(t_us), events_per_message)):
            e = slice(s, s + events_per_message)
            ev = np.empty(len(t_us[e]), dtype=ROS_EVENT_DTYPE)
            ev["x"], ev["y"] = np.asarray(x)[e], np.asarray(y)[e]
            ev["s"], ev["ns"] = t_us[e] // 1_000_000, (t_us[e] % 1_000_000) * 1000
            ev["p"] = np.asarray(p)[e] > 0
            frame_id = b"dvs"
            t_last = int(t_us[e][-1])
            head = np.array(
                [seq, t_last // 1_000_000, (t_last % 1_000_000) * 1000, len(frame_id)], "<u4"
            ).tobytes()
            raw = (
                head + frame_id + np.array([height, width, len(ev)], "<u4").tobytes() + ev.tobytes()
            )
            w.write(conn, t_last * 1000, raw)
        _write_side_data(w, ts, False, frames, camera, poses, int(t_us[0]) if len(t_us) else 0)
    return path


EVENT_PACKET_MSG = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\n"
    "string encoding\nbool is_bigendian\nuint8[] events\n"
)
"""``event_camera_msgs/msg/EventPacket`` (the definition its maintainers publish)."""


def write_rosbag2(
    path: str | Path,
    t_us: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    width: int,
    height: int,
    encoding: str = "libcaer",
    storage: str = "mcap",
    topic: str = "/event_camera/events",
    events_per_message: int = 5000,
    frames: list[tuple[int, np.ndarray]] | None = None,
    camera: Camera | None = None,
    poses: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """Write a ROS 2 bag (a folder; ``storage`` ``mcap`` or ``sqlite3``) of
    ``event_camera_msgs/EventPacket`` messages, as today's ROS 2 drivers record them.

    ``encoding``: ``libcaer`` (libcaer_driver's uncompressed packets: per event a uint32 address,
    bit 1 polarity, bits 2-16 y, bits 17-31 x, and an int32 time in us after the packet's
    ``time_base``, which is in ns) or ``evt3`` (metavision_driver: consecutive pieces of one EVT 3.0
    stream, :func:`encode_evt3`, split at word boundaries). Side data as :func:`write_rosbag1`, in
    ROS 2 (CDR) serialisation.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if encoding not in ("libcaer", "evt3"):
        raise ValueError(f"encoding {encoding!r}: libcaer or evt3")
    if encoding == "evt3" and len(t_us) and int(np.min(t_us)) >= 1 << 24:
        raise ValueError("evt3 holds sensor time that starts below 2^24 us (16.8 s); shift t_us")
    plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(EVENT_PACKET_MSG, "event_camera_msgs/msg/EventPacket"))
    T = ts.types
    path = Path(path)
    if path.exists():
        import shutil

        shutil.rmtree(path)
    t_us = np.asarray(t_us, dtype=np.int64)
    x, y, pol = np.asarray(x), np.asarray(y), np.asarray(p) > 0
    evt3 = encode_evt3(t_us, x, y, pol) if encoding == "evt3" else None
    n_msgs = -(-len(t_us) // events_per_message)
    with Writer(path, version=8, storage_plugin=plugins[storage]) as w:
        kind = "event_camera_msgs/msg/EventPacket"
        conn = w.add_connection(topic, kind, typestore=ts)
        for seq in range(n_msgs):
            e = slice(seq * events_per_message, (seq + 1) * events_per_message)
            t_last = int(t_us[e][-1])
            if evt3 is not None:  # pieces of one stream, cut at the same share of the words
                a, b = (len(evt3) * k // n_msgs for k in (seq, seq + 1))
                payload, time_base = evt3[a:b].tobytes(), 0
            else:
                tb = int(t_us[e][0])
                addr = (x[e].astype(np.uint32) << 17) | (y[e].astype(np.uint32) << 2)
                addr |= pol[e].astype(np.uint32) << 1
                rec = np.empty(len(addr), dtype=[("a", "<u4"), ("t", "<i4")])
                rec["a"], rec["t"] = addr, t_us[e] - tb
                payload, time_base = rec.tobytes(), tb * 1000
            msg = T[kind](
                header=_ros_header(T, True, seq, t_last),
                height=height,
                width=width,
                seq=seq,
                time_base=time_base,
                encoding=encoding,
                is_bigendian=False,
                events=np.frombuffer(payload, dtype=np.uint8),
            )
            w.write(conn, t_last * 1000, ts.serialize_cdr(msg, kind))
        _write_side_data(w, ts, True, frames, camera, poses, int(t_us[0]) if len(t_us) else 0)
    return path


def _ros_header(T, ros2: bool, seq: int, t_us: int):
    stamp = T["builtin_interfaces/msg/Time"](
        sec=t_us // 1_000_000, nanosec=(t_us % 1_000_000) * 1000
    )
    if ros2:  # ROS 2 headers have no seq
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id="dvs")
    return T["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id="dvs")


def _write_side_data(
    w,
    ts,
    ros2: bool,
    frames: list[tuple[int, np.ndarray]] | None,
    camera: Camera | None,
    poses: tuple[np.ndarray, np.ndarray] | None,
    t0_us: int,
) -> None:
    """Frames, camera info and poses (see :func:`write_rosbag1`) into the open bag writer ``w``."""
    from evdense.poses import poses_to_tum

    T = ts.types

    def put(topic: str, kind: str, items) -> None:
        c = w.add_connection(topic, kind, typestore=ts)
        for t, msg in items:
            w.write(
                c, t * 1000, ts.serialize_cdr(msg, kind) if ros2 else ts.serialize_ros1(msg, kind)
            )

    def images():
        for k, (ft, img) in enumerate(frames):
            img = np.ascontiguousarray(img, dtype=np.uint8)
            ch = 1 if img.ndim == 2 else img.shape[2]
            yield (
                int(ft),
                T["sensor_msgs/msg/Image"](
                    header=_ros_header(T, ros2, k, int(ft)),
                    height=img.shape[0],
                    width=img.shape[1],
                    encoding="mono8" if ch == 1 else "rgb8",
                    is_bigendian=0,
                    step=img.shape[1] * ch,
                    data=img.reshape(-1),
                ),
            )

    def pose_msgs():
        rows = poses_to_tum(np.asarray(poses[1]))
        for k, (tp, r) in enumerate(zip(np.asarray(poses[0]), rows, strict=True)):
            t_p = int(round(float(tp) * 1e6))
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=r[0], y=r[1], z=r[2]),
                orientation=T["geometry_msgs/msg/Quaternion"](x=r[3], y=r[4], z=r[5], w=r[6]),
            )
            yield (
                t_p,
                T["geometry_msgs/msg/PoseStamped"](header=_ros_header(T, ros2, k, t_p), pose=pose),
            )

    if frames:
        put("/dvs/image_raw", "sensor_msgs/msg/Image", images())
    if camera is not None:
        P = np.concatenate([camera.K, np.zeros((3, 1))], axis=1).reshape(-1)
        roi = T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        d, k, r, p = ("d", "k", "r", "p") if ros2 else ("D", "K", "R", "P")
        info = T["sensor_msgs/msg/CameraInfo"](
            header=_ros_header(T, ros2, 0, t0_us),
            height=camera.height,
            width=camera.width,
            distortion_model="plumb_bob",
            binning_x=0,
            binning_y=0,
            roi=roi,
            **{d: np.array([*camera.dist, 0.0]), k: camera.K.reshape(-1), r: np.eye(3).reshape(-1),
               p: P},
        )  # fmt: skip
        put("/dvs/camera_info", "sensor_msgs/msg/CameraInfo", [(t0_us, info)])
    if poses is not None:
        put("/optitrack/davis", "geometry_msgs/msg/PoseStamped", pose_msgs())


def write_rpg_text(
    folder: str | Path,
    t_us: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    p: np.ndarray,
    calib: Camera | None = None,
) -> Path:
    """Write ``events.txt`` (``t`` seconds with 6 decimals, ``p`` 0/1) and optionally ``calib.txt``.

    ``t_us`` int64 microseconds, ``p`` in {-1, +1} or {0, 1}. Returns the events.txt path.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    t_us = np.asarray(t_us, dtype=np.int64)
    sec, frac = np.divmod(t_us, 1_000_000)
    pp = (np.asarray(p) > 0).astype(np.int64)
    out = folder / "events.txt"
    with open(out, "w") as f:
        for s in range(0, len(t_us), 1 << 20):
            e = slice(s, s + (1 << 20))
            cols = np.stack([sec[e], frac[e], np.asarray(x)[e], np.asarray(y)[e], pp[e]], axis=1)
            np.savetxt(f, cols, fmt="%d.%06d %d %d %d")
    if calib is not None:
        (folder / "calib.txt").write_text(
            " ".join(
                f"{v:.10g}" for v in (calib.fx, calib.fy, calib.cx, calib.cy, *calib.dist, 0.0)
            )
            + "\n"
        )
    return out
