"""Bad input never crashes, never explodes memory and never passes as good (issue 21)."""

from __future__ import annotations

import subprocess
import sys
import zipfile

import h5py
import numpy as np
import pytest

from evdense.errors import InputError
from evdense.events.container import EventFile, Events, write_events
from evdense.io import ingest_recording
from evdense.testing.recordings import write_rpg_text


def _events(n, rng, w=64, h=48):
    t = np.sort(rng.integers(0, 1_000_000, n)).astype(np.int64)
    return Events(t, rng.integers(0, w, n).astype(np.uint16), rng.integers(0, h, n).astype(np.uint16),
                  np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8))  # fmt: skip


def test_many_blank_and_comment_lines_parse_with_right_line_numbers(tmp_path):
    lines = ["# a header"] + [""] * 100_000 + ["0.000001 1 2 1"] + ["", "% note"] * 7
    lines += ["0.000002 3 4 0", "", "0.000003 5 x 1"]
    (tmp_path / "events.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as e:
        ingest_recording(tmp_path / "events.txt", tmp_path / "out.h5", width=10, height=10)
    bad_line = len(lines)  # 1-based number of the last line
    assert f"line {bad_line}:" in str(e.value) and str(tmp_path / "events.txt") in str(e.value)
    assert not (tmp_path / "out.h5").exists()


def test_line_numbers_of_validation_errors_count_skipped_lines(tmp_path):
    lines = ["# header", "", "0.000001 1 2 1", "", "", "0.000002 99 4 0"]
    (tmp_path / "events.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="line 6"):
        ingest_recording(tmp_path / "events.txt", tmp_path / "out.h5", width=10, height=10)


def test_time_index_follows_the_event_count_not_the_time_span(tmp_path):
    ev = Events(np.array([0, 5, 10**12], np.int64), np.array([1, 2, 3], np.uint16),
                np.array([0, 1, 2], np.uint16), np.array([1, -1, 1], np.int8))  # fmt: skip
    path = write_events(tmp_path / "e.h5", ev, 8, 8)  # last event 10^6 s after the first
    with h5py.File(path) as f:
        assert f["t_index"].shape == (2,) and f["t_index_key"].shape == (2,)
    with EventFile(path) as f:
        assert [f.index_at(t) for t in (-5, 0, 1, 6, 10**9, 10**12, 10**12 + 1)] == [
            0,
            0,
            1,
            2,
            2,
            2,
            3,
        ]
        assert len(f.read_time(0, 10**12)) == 2


def test_converting_a_huge_time_span_stays_small(tmp_path):
    # Three events 10^6 s apart: memory must follow the events, not the time span (a dense
    # per-millisecond index would be 8 GB). Measured as the growth of the peak over converting
    # a 1 s span in the same process, so imports, JIT compilation and per-thread buffers (which
    # grow with the machine's core count) cancel out.
    for name, t_last in (("short", 10**6), ("huge", 10**12)):
        write_rpg_text(tmp_path / name, np.array([0, 1, t_last]), np.array([0, 1, 2]),
                       np.array([0, 1, 2]), np.array([1, -1, 1]))  # fmt: skip
    code = (
        "import resource, sys\n"
        "from evdense.io import ingest_recording\n"
        "peak = []\n"
        "for src in sys.argv[1:]:\n"
        "    ingest_recording(src + '/events.txt', src + '/e.h5', width=8, height=8)\n"
        "    peak.append(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
        "print(peak[1] - peak[0])\n"
    )
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "short"),
                          str(tmp_path / "huge")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.split()[-1]) < 64_000  # KiB


@pytest.mark.parametrize("damage", ["backwards", "off_sensor", "polarity", "columns"])
def test_damaged_canonical_file_is_refused_on_read(tmp_path, rng, damage):
    path = write_events(tmp_path / "e.h5", _events(1000, rng), 64, 48)
    with h5py.File(path, "r+") as f:
        if damage == "backwards":
            t = f["events/t"][()]
            t[500:508] = t[500:508][::-1] - 1000
            f["events/t"][...] = t
        elif damage == "off_sensor":
            f["events/x"][700] = 64
        elif damage == "polarity":
            f["events/p"][10] = 0
        else:
            del f["events/p"]
            f.create_dataset("events/p", data=np.ones(10, np.int8))
    with pytest.raises(InputError) as e:
        with EventFile(path) as f:
            for _ in f.iter_chunks(256):
                pass
    assert str(path) in str(e.value) and "damaged" in str(e.value)


def test_side_data_failure_leaves_no_complete_looking_event_file(tmp_path, rng):
    ev = _events(200, rng)
    write_rpg_text(tmp_path / "rec", ev.t, ev.x, ev.y, ev.p)
    (tmp_path / "rec" / "images.txt").write_text("0.0 images/missing.png\n")
    out = tmp_path / "out" / "events.h5"
    with pytest.raises(InputError, match="missing.png"):
        ingest_recording(tmp_path / "rec", out, conventional_dir=tmp_path / "out" / "conv",
                         width=64, height=48)  # fmt: skip
    assert sorted(p.name for p in out.parent.iterdir()) == ["conv"]


def test_foreign_library_errors_become_ours(tmp_path, rng):
    ev = _events(200, rng)
    write_rpg_text(tmp_path / "rec", ev.t, ev.x, ev.y, ev.p)
    z = tmp_path / "rec.zip"
    with zipfile.ZipFile(z, "w", zipfile.ZIP_DEFLATED) as f:
        f.write(tmp_path / "rec" / "events.txt", "rec/events.txt")
    data = bytearray(z.read_bytes())
    data[60:90] = b"\xff" * 30  # inside the deflated stream
    z.write_bytes(bytes(data))
    with pytest.raises(InputError) as e:
        ingest_recording(z, tmp_path / "out.h5", width=64, height=48)
    assert str(z) in str(e.value)


def test_cli_prints_one_line_and_exits_2(tmp_path):
    (tmp_path / "events.txt").write_text("0.1 1 2 1\n0.2 1 2\n")
    out = subprocess.run([sys.executable, "-m", "evdense.cli", "convert", str(tmp_path / "events.txt"),
                          str(tmp_path / "e.h5")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 2
    errors = [ln for ln in out.stderr.splitlines() if "ERROR" in ln]
    assert len(errors) == 1 and "line 2" in errors[0] and "Traceback" not in out.stderr


@pytest.mark.parametrize("size", [b"99999999999", b"1099511627776", b"-5"])
def test_absurd_sensor_size_in_a_header_is_refused(tmp_path, rng, size):
    from evdense.testing.recordings import write_evt2

    ev = _events(100, rng)
    path = write_evt2(tmp_path / "r.raw", ev.t, ev.x, ev.y, ev.p, 64, 48)
    data = path.read_bytes()
    path.write_bytes(data.replace(b"width=64", b"width=" + size).replace(b"64x48", size + b"x48"))
    assert path.read_bytes() != data
    with pytest.raises(InputError, match="sensor size|width"):
        ingest_recording(path, tmp_path / "e.h5")


@pytest.mark.parametrize("t", [[-5, 1, 2], [0, 1, 2**63 + 5], [0, 1, 2**60]])
def test_out_of_range_timestamps_are_refused(tmp_path, t):
    from evdense.testing.recordings import write_npz

    write_npz(tmp_path / "r.npz", np.array(t, dtype=np.uint64 if t[-1] >= 2**63 else np.int64),
              np.array([1, 2, 3]), np.array([1, 2, 3]), np.array([1, -1, 1]))  # fmt: skip
    with pytest.raises(InputError, match="timestamp"):
        ingest_recording(tmp_path / "r.npz", tmp_path / "e.h5", width=8, height=8)


def test_seconds_of_1e300_are_refused(tmp_path):
    (tmp_path / "events.txt").write_text("0.5 1 1 1\n1e300 1 1 0\n")
    with pytest.raises(InputError, match="line 2|out of range"):
        ingest_recording(tmp_path / "events.txt", tmp_path / "e.h5", width=8, height=8)


@pytest.mark.parametrize(
    ("config", "key"),
    [
        ({"datasets": {"../../escaped": {"scene": "room"}}}, "datasets.../../escaped"),
        ({"datasets": {"ok": {"scene": "room", "sped": 4}}}, "datasets.ok"),
        ({"datasets": {}}, "datasets"),
        ({}, "datasets"),
    ],
)
def test_config_refuses_unsafe_names_typos_and_nothing_to_do(config, key):
    from evdense.config import ConfigError, check_config, validate_config

    with pytest.raises(ConfigError) as e:
        check_config(validate_config(config))  # the workflow runs both, in this order
    assert f"'{key}'" in str(e.value)


def test_key_order_does_not_change_the_validated_config():
    import json

    from evdense.config import validate_config

    a = validate_config({"datasets": {"r": {"scene": "room", "speed": 4}, "d": {"scene": "desk"}},
                         "mesh": {"refine": {"max_seconds": 45}}, "reconstruct": {"methods": ["ours"]}})  # fmt: skip
    b = validate_config({"reconstruct": {"methods": ["ours"]}, "mesh": {"refine": {"max_seconds": 45}},
                         "datasets": {"d": {"scene": "desk"}, "r": {"speed": 4, "scene": "room"}}})  # fmt: skip
    assert json.dumps(a) == json.dumps(b) and repr(a["mesh"]) == repr(b["mesh"])


def test_image_paths_stay_inside_the_recording(tmp_path, rng):
    ev = _events(100, rng)
    write_rpg_text(tmp_path / "rec", ev.t, ev.x, ev.y, ev.p)
    secret = tmp_path / "secret.png"
    import imageio.v3 as iio

    iio.imwrite(secret, np.zeros((48, 64), np.uint8))
    for rel in ("../secret.png", str(secret)):
        (tmp_path / "rec" / "images.txt").write_text(f"0.0 {rel}\n")
        with pytest.raises(InputError, match="outside the recording"):
            ingest_recording(tmp_path / "rec", tmp_path / "e.h5",
                             conventional_dir=tmp_path / "conv", width=64, height=48)  # fmt: skip
        assert not (tmp_path / "conv" / "frames").exists()


def test_mcap_record_length_beyond_the_file_is_refused_before_reading(tmp_path, anchors):
    import shutil
    import struct

    src = anchors / "data" / "ros" / "event_camera_msgs_evt3_ros2"
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    data[9:17] = struct.pack("<Q", 2**61)  # the first record's length: rosbags would allocate it
    mcap.write_bytes(bytes(data))
    with pytest.raises(InputError) as e:
        ingest_recording(bag, tmp_path / "e.h5")
    assert str(mcap) in str(e.value) and "byte offset 8" in str(e.value)
    assert not (tmp_path / "e.h5").exists()
