"""Readers of real recordings: every writer/reader pair preserves every event; the real AEDAT4
sample decodes to its known content; side data (frames, calibration, trajectory) reaches our layout."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from evdense.camera import Camera, load_camera
from evdense.events.container import EventFile, Events, write_events
from evdense.io import detect_format, ingest_recording, open_recording, validate_stream
from evdense.io.prophesee import read_header
from evdense.poses import look_at, read_tum, write_tum
from evdense.testing.recordings import (
    write_aedat4,
    write_dat,
    write_e2vid_h5,
    write_evt2,
    write_evt3,
    write_npy,
    write_npz,
    write_rosbag1,
    write_rosbag2,
    write_rpg_text,
)

W, H = 346, 260


def random_stream(
    rng: np.random.Generator, n: int = 5000, t0: int = 0, w: int = W, h: int = H
) -> Events:
    """Sorted timestamps with repeats (us), coordinates over the whole sensor, polarity +-1."""
    t = t0 + np.cumsum(rng.integers(0, 40, n))
    return Events(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.choice([-1, 1], n))


def read_all(
    path: Path, fmt: str = "auto", w: int | None = None, h: int | None = None, **kw
) -> tuple[Events, object]:
    with open_recording(path, fmt, chunk_events=1000, **kw) as rec:
        ww, hh = w or rec.width, h or rec.height
        ev = Events.concatenate(list(validate_stream(rec.iter_events(), path, ww, hh)))
        return ev, (rec.format, rec.width, rec.height)


def assert_same(a: Events, b: Events) -> None:
    assert len(a) == len(b)
    for k in "txyp":
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)


# --- round trips ---------------------------------------------------------------------------------
def test_rpg_text_round_trip_file_folder_zip(tmp_path, rng):
    ev = random_stream(rng, t0=1_500_000_000_000_000)  # absolute Unix time in us: precision matters
    events_txt = write_rpg_text(tmp_path / "seq", ev.t, ev.x, ev.y, ev.p)
    for src in (events_txt, tmp_path / "seq"):
        got, (fmt, _, _) = read_all(src, w=W, h=H)
        assert fmt == "rpg_text"
        assert_same(got, ev)
    z = tmp_path / "seq.zip"
    with zipfile.ZipFile(z, "w") as zf:
        zf.write(events_txt, "seq/events.txt")
    assert detect_format(z) == "rpg_text"
    assert_same(read_all(z, w=W, h=H)[0], ev)


def test_rpg_text_nanosecond_digits_round_to_microseconds(tmp_path):
    f = tmp_path / "events.txt"
    f.write_text(
        "# t x y p\n1468939993.067416500 1 2 1\n1468939993.067416499 3 4 0\n\n0.0000015 5 6 1\n"
    )
    with open_recording(f) as rec:
        (b,) = list(rec.iter_events())
    assert b.t.tolist() == [1468939993067417, 1468939993067416, 2]
    assert b.x.tolist() == [1, 3, 5] and b.p.tolist() == [1, 0, 1]
    assert b.where(2) == "event 2 (line 5)"  # the comment and the blank line are counted


def test_e2vid_h5_round_trip_seconds_and_microseconds(tmp_path, rng):
    ev = random_stream(rng, t0=1_600_000_000_000_000)
    for seconds in (True, False):
        f = write_e2vid_h5(
            tmp_path / f"e_{seconds}.h5", ev.t, ev.x, ev.y, ev.p, W, H, ts_seconds=seconds
        )
        got, (fmt, w, h) = read_all(f)
        assert (fmt, w, h) == ("e2vid_h5", W, H)
        assert_same(got, ev)


def test_e2vid_h5_frames_reach_the_conventional_folder(tmp_path, rng):
    import imageio.v3 as iio

    ev = random_stream(rng, n=500)
    frames = [(int(ev.t[k]), rng.integers(0, 256, (H, W), dtype=np.uint8)) for k in (0, 250, 499)]
    f = write_e2vid_h5(tmp_path / "e.h5", ev.t, ev.x, ev.y, ev.p, W, H, frames=frames)
    res = ingest_recording(
        f, tmp_path / "o" / "events.h5", conventional_dir=tmp_path / "o" / "conv"
    )
    assert res.num_frames == 3
    for k, (_, img) in enumerate(frames):
        np.testing.assert_array_equal(
            iio.imread(tmp_path / "o" / "conv" / "frames" / f"{k:06d}.png"), img
        )


def test_numpy_round_trips(tmp_path, rng):
    ev = random_stream(rng)
    for compressed in (False, True):
        f = write_npz(
            tmp_path / f"e{compressed}.npz", ev.t, ev.x, ev.y, ev.p, W, H, compressed=compressed
        )
        got, (fmt, w, h) = read_all(f)
        assert (fmt, w, h) == ("numpy", W, H)
        assert_same(got, ev)
    f = write_npy(tmp_path / "e.npy", ev.t, ev.x, ev.y, ev.p)
    assert_same(read_all(f, w=W, h=H)[0], ev)


def test_numpy_float_seconds_and_other_field_names(tmp_path, rng):
    ev = random_stream(rng, n=300)
    np.savez(
        tmp_path / "f.npz",
        timestamp=ev.t * 1e-6,
        xs=ev.x.astype(np.int32),
        ys=ev.y,
        polarity=ev.p > 0,
    )
    assert_same(read_all(tmp_path / "f.npz", w=W, h=H)[0], ev)


def test_dat_round_trip(tmp_path, rng):
    ev = random_stream(rng)
    f = write_dat(tmp_path / "e.dat", ev.t, ev.x, ev.y, ev.p, W, H)
    got, (fmt, w, h) = read_all(f)
    assert (fmt, w, h) == ("prophesee_dat", W, H)
    assert_same(got, ev)


def test_dat_unwraps_32_bit_time(tmp_path, rng):
    ev = random_stream(rng, n=2000, t0=(1 << 32) - 20_000)
    wrapped = ev.t % (1 << 32)
    f = tmp_path / "w.dat"
    write_dat(f, wrapped, ev.x, ev.y, ev.p, W, H)
    got, _ = read_all(f)
    np.testing.assert_array_equal(got.t, ev.t - ev.t[0] + wrapped[0])


@pytest.mark.parametrize("writer,fmt", [(write_evt2, "evt2"), (write_evt3, "evt3")])
def test_raw_round_trip(tmp_path, rng, writer, fmt):
    ev = random_stream(rng, w=1280, h=720)
    f = writer(tmp_path / "e.raw", ev.t, ev.x, ev.y, ev.p, 1280, 720)
    assert detect_format(f) == fmt
    got, (name, w, h) = read_all(f)
    assert (name, w, h) == ("prophesee_raw", 1280, 720)
    assert_same(got, ev)


def test_evt3_vectors_and_24_bit_wrap(tmp_path, rng):
    # runs of events sharing time, row and polarity become VECT_12 words; the stream crosses the
    # 24-bit (16.8 s) wrap of the EVT3 time base twice
    n_runs = 400
    t = np.repeat(np.sort(rng.integers(16_000_000, 40_000_000, n_runs)), 5)
    y = np.repeat(rng.integers(0, 720, n_runs), 5)
    p = np.repeat(rng.choice([-1, 1], n_runs), 5)
    x = (np.repeat(rng.integers(0, 1200, n_runs), 5) + np.tile([0, 1, 3, 7, 11], n_runs)).astype(
        np.int64
    )
    f = write_evt3(tmp_path / "v.raw", t, x, y, p, 1280, 720)
    _, data_offset = read_header(f)
    assert (f.stat().st_size - data_offset) // 2 < len(t)  # vectorised: fewer words than events
    got, _ = read_all(f)
    assert_same(got, Events(t, x, y, p))


@pytest.mark.parametrize("compression", [0, 1, 3])
def test_aedat4_round_trip_with_frames(tmp_path, rng, compression):
    ev = random_stream(rng, t0=1_605_537_493_718_345)
    frames = [
        (int(ev.t[100]), rng.integers(0, 256, (H, W), dtype=np.uint8)),
        (int(ev.t[3000]), rng.integers(0, 256, (H, W, 3), dtype=np.uint8)),
    ]
    f = write_aedat4(
        tmp_path / "e.aedat4", ev.t, ev.x, ev.y, ev.p, W, H, frames=frames, compression=compression
    )
    got, (fmt, w, h) = read_all(f)
    assert (fmt, w, h) == ("aedat4", W, H)
    assert_same(got, ev)
    with open_recording(f) as rec:
        fr = list(rec.iter_frames())
    assert [x.t_us for x in fr] == [frames[0][0], frames[1][0]]
    for a, (_, b) in zip(fr, frames, strict=True):
        np.testing.assert_array_equal(a.image, b)


def test_rosbag_round_trip(tmp_path, rng):
    ev = random_stream(rng, t0=1_468_939_993_000_000)
    f = write_rosbag1(tmp_path / "e.bag", ev.t, ev.x, ev.y, ev.p, W, H, events_per_message=777)
    got, (fmt, w, h) = read_all(f)
    assert (fmt, w, h) == ("rosbag", W, H)
    assert_same(got, ev)


@pytest.mark.parametrize("encoding,storage", [("libcaer", "mcap"), ("evt3", "sqlite3")])
def test_rosbag2_event_packets_round_trip(tmp_path, rng, encoding, storage):
    # EVT 3.0 holds 24-bit sensor time (the reader unrolls its wraps from the first word on)
    ev = random_stream(rng, t0=1_468_939_993_000_000 if encoding == "libcaer" else 16_700_000)
    f = write_rosbag2(tmp_path / "bag", ev.t, ev.x, ev.y, ev.p, W, H, encoding=encoding,
                      storage=storage, events_per_message=777)  # fmt: skip
    got, (fmt, w, h) = read_all(f)
    assert (fmt, w, h) == ("rosbag", W, H)
    assert_same(got, ev)


ROS_BAGS = {
    "ros1": lambda path, *a, **kw: write_rosbag1(path.with_suffix(".bag"), *a, **kw),
    "ros2": lambda path, *a, **kw: write_rosbag2(path, *a, encoding="libcaer", **kw),
}


@pytest.mark.parametrize("bag", sorted(ROS_BAGS))
def test_rosbag_frames_camera_info_and_poses(tmp_path, rng, bag):
    ev = random_stream(rng, n=3000, t0=1_468_939_993_000_000)
    frames = [(int(ev.t[10]), rng.integers(0, 256, (H, W), dtype=np.uint8))]
    frames.append((int(ev.t[2000]), rng.integers(0, 256, (H, W, 3), dtype=np.uint8)))
    cam = Camera(W, H, 251.0, 252.0, 170.5, 130.5, (-0.2, 0.05, 0.001, -0.002))
    t_gt = (ev.t[[0, 1000, 2000]] * 1e-6).round(6)
    T = np.stack(
        [look_at(np.array([0.1 * i, 0.0, 0.0]), np.array([0.0, 0.0, 2.0])) for i in range(3)]
    )
    f = ROS_BAGS[bag](
        tmp_path / "e", ev.t, ev.x, ev.y, ev.p, W, H, frames=frames, camera=cam, poses=(t_gt, T)
    )
    out = tmp_path / "out"
    res = ingest_recording(f, out / "events.h5", out / "conventional", out / "gt")
    assert res.num_events == len(ev) and res.num_frames == 2 and res.num_poses == 3
    import imageio.v3 as iio

    for k, (_, img) in enumerate(frames):
        np.testing.assert_array_equal(
            iio.imread(out / "conventional" / "frames" / f"{k:06d}.png"), img
        )
    lines = (out / "conventional" / "frames" / "timestamps.txt").read_text().split()
    assert lines[1] == f"{frames[0][0] // 1_000_000}.{frames[0][0] % 1_000_000:06d}"
    assert load_camera(out / "gt" / "intrinsics.yaml") == cam
    t2, T2 = read_tum(out / "gt" / "trajectory.txt")
    np.testing.assert_allclose(t2, t_gt, atol=1e-6)
    np.testing.assert_allclose(T2, T, atol=1e-8)


def test_canonical_file_as_input(tmp_path, rng):
    ev = random_stream(rng)
    f = write_events(tmp_path / "c.h5", ev, W, H)
    got, (fmt, w, h) = read_all(f)
    assert (fmt, w, h) == ("evdense", W, H)
    assert_same(got, ev)


# --- the real AEDAT4 recording --------------------------------------------------------------------
def test_real_dvxplorer_aedat4(anchors, tmp_path):
    src = anchors / "data" / "dvxplorer_sample.aedat4"
    assert detect_format(src) == "aedat4"
    res = ingest_recording(src, tmp_path / "events.h5", manifest_out=tmp_path / "m.json")
    assert (res.num_events, res.width, res.height) == (111_954, 320, 240)
    assert res.corrections == []
    with EventFile(tmp_path / "events.h5") as ef:
        assert (ef.num_events, ef.width, ef.height) == (111_954, 320, 240)
        assert ef.duration_s == pytest.approx(0.59, abs=0.005)
        ev = ef.read()
    assert ev.x.max() < 320 and ev.y.max() < 240
    assert set(np.unique(ev.p)) == {-1, 1}
    # a 2020 recording: absolute microseconds since the Unix epoch
    assert 1.6e15 < ev.t[0] < 1.61e15
    assert json.loads((tmp_path / "m.json").read_text())["num_events"] == 111_954


# --- ingest: side data ----------------------------------------------------------------------------
def test_ingest_rpg_folder_with_calib_images_groundtruth(tmp_path, rng):
    import imageio.v3 as iio

    seq = tmp_path / "shapes"
    ev = random_stream(rng, w=240, h=180)
    cam = Camera(240, 180, 199.1, 198.7, 132.2, 110.1, (-0.37, 0.16, 0.0, 0.0))
    write_rpg_text(seq, ev.t, ev.x, ev.y, ev.p, calib=cam)
    (seq / "images").mkdir()
    imgs = [rng.integers(0, 256, (180, 240), dtype=np.uint8) for _ in range(3)]
    lines = []
    for k, img in enumerate(imgs):
        iio.imwrite(seq / "images" / f"frame_{k:08d}.png", img)
        lines.append(f"{0.05 * k + 0.0123456789:.9f} images/frame_{k:08d}.png")
    (seq / "images.txt").write_text("\n".join(lines) + "\n")
    t_gt = np.array([0.0, 0.01, 0.02])
    T = np.stack(
        [
            look_at(np.array([i, 0.0, 0.0]), np.array([i, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]))
            for i in range(3)
        ]
    )
    write_tum(seq / "groundtruth.txt", t_gt, T)

    out = tmp_path / "results" / "shapes"
    res = ingest_recording(
        seq / "events.txt",
        out / "events" / "events.h5",
        conventional_dir=out / "conventional",
        gt_dir=out / "gt",
        manifest_out=out / "events" / "ingest.json",
        width=240,
        height=180,
    )
    assert res.num_events == len(ev) and res.sensor_size_source == "config"
    frames = out / "conventional" / "frames"
    assert sorted(p.name for p in frames.glob("*.png")) == [
        "000000.png",
        "000001.png",
        "000002.png",
    ]
    np.testing.assert_array_equal(iio.imread(frames / "000001.png"), imgs[1])
    ts = [line.split() for line in (frames / "timestamps.txt").read_text().splitlines()]
    assert ts == [["0", "0.012346"], ["1", "0.062346"], ["2", "0.112346"]]
    assert load_camera(out / "gt" / "intrinsics.yaml") == cam
    t2, T2 = read_tum(out / "gt" / "trajectory.txt")
    np.testing.assert_allclose(t2, t_gt)
    np.testing.assert_allclose(T2, T, atol=1e-8)
    m = json.loads((out / "events" / "ingest.json").read_text())
    assert m["num_frames"] == 3 and m["trajectory"] and m["intrinsics"]
    with EventFile(out / "events" / "events.h5") as ef:
        assert ef.attrs["camera"]["fx"] == pytest.approx(199.1)
        assert ef.attrs["source_format"] == "rpg_text"


def test_ingest_without_side_data_creates_empty_folders(tmp_path, rng):
    ev = random_stream(rng)
    f = write_npz(tmp_path / "e.npz", ev.t, ev.x, ev.y, ev.p, W, H)
    res = ingest_recording(
        f,
        tmp_path / "o" / "events.h5",
        tmp_path / "o" / "conventional",
        tmp_path / "o" / "gt",
        tmp_path / "o" / "m.json",
    )
    assert (tmp_path / "o" / "conventional").is_dir() and (tmp_path / "o" / "gt").is_dir()
    assert list((tmp_path / "o" / "gt").iterdir()) == []
    assert res.frames is None and res.trajectory is None and res.intrinsics is None


def test_ingest_calibration_file_overrides_and_must_match_sensor(tmp_path, rng, anchors):
    ev = random_stream(rng)
    f = write_npz(tmp_path / "e.npz", ev.t, ev.x, ev.y, ev.p, W, H)
    cal = anchors / "data" / "davis346_vins_calib.yaml"
    res = ingest_recording(f, tmp_path / "a.h5", gt_dir=tmp_path / "gt", calibration=cal)
    assert load_camera(tmp_path / "gt" / "intrinsics.yaml").fx == pytest.approx(613.46, abs=0.01)
    assert res.intrinsics_source == str(cal)
    with pytest.raises(ValueError, match="346x260 image but the sensor is 320x240"):
        ingest_recording(f, tmp_path / "b.h5", calibration=cal, width=320, height=240, config=None)
    assert not (tmp_path / "b.h5").exists()


def test_cli_convert(tmp_path, rng):
    from evdense.cli import main

    ev = random_stream(rng)
    src = write_dat(tmp_path / "e.dat", ev.t, ev.x, ev.y, ev.p, W, H)
    assert main(["convert", str(src), str(tmp_path / "out.h5")]) == 0
    with EventFile(tmp_path / "out.h5") as ef:
        assert_same(ef.read(), ev)
    # a clear failure, no output
    assert (
        main(["convert", str(src), str(tmp_path / "bad.h5"), "--width", "100", "--height", "100"])
        == 2
    )
    assert not (tmp_path / "bad.h5").exists()


# --- event_camera_msgs/EventPacket and Prophesee samples (real files) -------------------------------
def _packet(encoding: str, payload: bytes, time_base: int = 0, w: int = W, h: int = H):
    from evdense.io.event_packets import EventPacket

    return EventPacket(0, h, w, 0, time_base, encoding, False, memoryview(payload))


def test_libcaer_cmp_words_decode_to_known_events():
    from evdense.io.event_packets import PacketDecoder

    words = [
        0x0000 | 1,  # time high: 1 * 4096 us
        0x1000 | 5,  # time low: 5 us
        0x2000 | 17,  # x = 17
        0x3000 | 0x800 | 9,  # y = 9, ON: event (17, 9, 1) at 4101 us
        0x1000 | 7,  # time low: 7 us
        0x4000 | 40,  # vector base y = 40, OFF
        0x5000 | 0b10000001,  # rows 40 and 47
        0x5000 | 0b00000010,  # base moved to 48: row 49
        0x7000 | 123,  # unknown type: skipped
        0x2000 | 400,  # x beyond the 346-wide sensor: dropped
        0x3000 | 3,
    ]
    dec = PacketDecoder("test")
    t, x, y, p = dec.decode(_packet("libcaer_cmp", np.array(words, "<u2").tobytes(), 2_000_000), 0)
    assert list(zip(t.tolist(), x.tolist(), y.tolist(), p.tolist(), strict=True)) == [
        (2000 + 4101, 17, 9, 1), (2000 + 4103, 17, 40, 0), (2000 + 4103, 17, 47, 0),
        (2000 + 4103, 17, 49, 0),
    ]  # fmt: skip
    assert dec.dropped_off_sensor == 1


def test_libcaer_uncompressed_unrolls_the_32_bit_counter():
    from evdense.io.event_packets import PacketDecoder

    addr = lambda x, y, p: (x << 17) | (y << 2) | (p << 1)  # noqa: E731
    rec = np.array([(addr(3, 4, 1), 2**31 - 10), (addr(5, 6, 0), 2**31 - 1), (addr(7, 8, 1), 5)],
                   dtype=[("a", "<u4"), ("t", "<i4")])  # fmt: skip
    t, x, y, p = PacketDecoder("test").decode(_packet("libcaer", rec.tobytes()), 0)
    assert t.tolist() == [2**31 - 10, 2**31 - 1, 2**31 + 5]
    assert (x.tolist(), y.tolist(), p.tolist()) == ([3, 5, 7], [4, 6, 8], [1, 0, 1])


def test_unsupported_packet_encoding_is_named():
    from evdense.io.event_packets import PacketDecoder

    with pytest.raises(ValueError, match="'trigger' is not supported"):
        PacketDecoder("bag: /events").decode(_packet("trigger", b"\0" * 8), 3)


def test_real_ros1_event_packets_evt3(anchors):
    src = anchors / "data" / "ros" / "event_camera_msgs_evt3.bag"
    ev, (fmt, w, h) = read_all(src)
    # counts of the message package's own maintainers' decoder (anchors README)
    assert (fmt, w, h, len(ev)) == ("rosbag", 640, 480, 343_474)
    assert ((ev.p < 0).sum(), (ev.p > 0).sum()) == (218_291, 125_183)
    assert (ev.t[-1] - ev.t[0]) / 1e6 == pytest.approx(2.08, abs=0.01)


def test_real_ros2_event_packets_libcaer_cmp(anchors):
    src = (
        anchors / "data" / "ros" / "event_camera_msgs_evt3_ros2"
    )  # mcap, a DAVIS346 despite its name
    assert detect_format(src) == "rosbag"
    ev, (fmt, w, h) = read_all(src)
    assert (fmt, w, h) == ("rosbag", 346, 260)
    assert len(ev) == 571_266 and (ev.p > 0).sum() == 211_043
    # the first events, decoded by hand from the first packet's words
    assert (ev.t[:3] - ev.t[0]).tolist() == [0, 1, 3]
    assert list(zip(ev.x[:3].tolist(), ev.y[:3].tolist(), ev.p[:3].tolist(), strict=True)) == [
        (219, 244, -1), (249, 254, 1), (288, 168, -1)]  # fmt: skip
    assert (ev.t[-1] - ev.t[0]) / 1e6 == pytest.approx(1.0, abs=0.01)


def test_real_evt3_timestamps_are_exact(anchors, tmp_path):
    # TIME_LOW sets the low 12 bits of the time and TIME_HIGH the 12 above them, each as it comes
    # (EVT 3.0 documentation): a TIME_LOW smaller than the last one without a TIME_HIGH between
    # is the sensor's own out-of-order word, not a wrap, and is kept as it is (faery clamps it,
    # expelliarmus adds 4096 us). Chosen events checked by hand against the words.
    src = anchors / "data" / "prophesee" / "evt3_sample.raw"
    res = ingest_recording(src, tmp_path / "e.h5")  # sensor size from the header's plugin name
    assert (res.num_events, res.width, res.height) == (219_596, 1280, 720)
    with EventFile(tmp_path / "e.h5") as f:
        ev = f.read()
    for i, (t, x, y, p) in {0: (11_718_656, 874, 200, -1), 20_121: (11_719_456, 152, 661, -1),
                            219_595: (11_727_457, 1218, 572, 1)}.items():  # fmt: skip
        assert (ev.t[i], ev.x[i], ev.y[i], ev.p[i]) == (t, x, y, p), i
    assert ((ev.p > 0).sum(), (ev.p < 0).sum()) == (115_532, 104_064)


def test_real_evt2_sample(anchors, tmp_path):
    src = anchors / "data" / "prophesee" / "evt2_sample.raw"
    res = ingest_recording(src, tmp_path / "e.h5")
    assert (res.num_events, res.width, res.height) == (539_481, 640, 480)
    with EventFile(tmp_path / "e.h5") as f:
        ev = f.read()
    assert (ev.t[0], ev.t[-1]) == (1_317_888, 1_367_888)
    assert (ev.t[1000], ev.x[1000], ev.y[1000], ev.p[1000]) == (1_317_979, 262, 94, -1)
    assert ((ev.p > 0).sum(), (ev.p < 0).sum()) == (367_855, 171_626)


def test_cli_info_describes_a_real_recording_without_converting(anchors, tmp_path, capsys):
    from evdense.cli import main

    src = anchors / "data" / "ecd_slider_depth"
    before = sorted(p.name for p in src.iterdir())
    assert main(["info", str(src), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["format"], info["events"], info["frames"], info["gt_poses"]) == (
        "rpg_text", 50_000, 87, 339)  # fmt: skip
    assert info["frame_size"] == [240, 180] and info["sensor"] == [240, 180]
    assert info["calibration"]["fx"] == pytest.approx(335.419, abs=1e-3)
    assert 0.16 < info["duration_s"] < 0.18 and 0 < info["on_fraction"] < 1
    assert sorted(p.name for p in src.iterdir()) == before  # nothing written beside it
    assert main(["info", str(tmp_path / "missing.aedat4")]) == 2  # a clear error, no traceback


def test_cli_reconstruct_writes_a_config_and_plans_the_run(anchors, tmp_path):
    import yaml

    from evdense.cli import main

    src = anchors / "data" / "ecd_slider_depth"
    assert main(["reconstruct", str(src), "--out", str(tmp_path), "--dry-run"]) == 0
    conf = yaml.safe_load((tmp_path / "config.yaml").read_text())
    assert conf["datasets"] == {"ecd_slider_depth": {"recording": str(src.resolve()),
                                                     "format": "auto"}}  # fmt: skip
    assert conf["reconstruct"]["methods"] == ["ours"]
    assert not (tmp_path / "results").exists()  # a dry run makes nothing
