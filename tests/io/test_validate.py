"""Bad input: each case ends in a clear error naming the file and the position, or in an explicit,
logged correction; never in silent garbage and never in a complete-looking output."""

from __future__ import annotations

import logging

import h5py
import numpy as np
import pytest

from evdense.events.container import EventFile, Events
from evdense.io import (
    IngestConfig,
    RawEvents,
    ValidationConfig,
    ValidationReport,
    detect_format,
    ingest_recording,
    open_recording,
    validate_stream,
)
from evdense.testing.recordings import (
    write_aedat4,
    write_dat,
    write_e2vid_h5,
    write_evt3,
    write_npz,
    write_rpg_text,
)

W, H = 64, 48


def stream(rng: np.random.Generator, n: int = 2000) -> Events:
    t = np.cumsum(rng.integers(1, 50, n))
    return Events(t, rng.integers(0, W, n), rng.integers(0, H, n), rng.choice([-1, 1], n))


def run(path, cfg: IngestConfig | None = None, **kw):
    return ingest_recording(
        path, path.parent / "out.h5", config=cfg or IngestConfig(chunk_events=500), **kw
    )


def text_file(tmp_path, lines: list[str]):
    f = tmp_path / "events.txt"
    f.write_text("\n".join(lines) + "\n")
    return f


# --- time order ------------------------------------------------------------------------------------
def test_out_of_order_events_are_sorted_and_logged(tmp_path, rng, caplog):
    ev = stream(rng)
    t = ev.t.copy()
    swap = np.arange(100, 1900, 150)  # 12 adjacent swaps, some across the 500-event batches
    t[swap], t[swap + 1] = ev.t[swap + 1], ev.t[swap]
    write_rpg_text(tmp_path, t, ev.x, ev.y, ev.p)
    with caplog.at_level(logging.WARNING, logger="evdense"):
        res = run(tmp_path / "events.txt", width=W, height=H)
    assert res.validation["out_of_order"] == 12
    assert "sorted 12 out-of-order events" in caplog.text
    with EventFile(tmp_path / "out.h5") as ef:
        got = ef.read()
    np.testing.assert_array_equal(got.t, np.sort(t))
    assert len(got) == len(ev)


def test_out_of_order_is_an_error_when_asked(tmp_path):
    f = text_file(tmp_path, ["0.000010 1 1 1", "0.000020 2 2 0", "0.000015 3 3 1"])
    with pytest.raises(
        ValueError, match=r"events\.txt: timestamps go back in time at event 2 \(line 3\)"
    ):
        run(f, IngestConfig(unsorted="error"), width=W, height=H)
    assert not (tmp_path / "out.h5").exists()
    assert not (tmp_path / "out.h5.partial").exists()


def test_disorder_beyond_the_window_is_an_error(tmp_path, rng):
    ev = stream(rng, 3000)
    t = ev.t.copy()
    t[2500] = t[100]  # jumps back ~ 60 ms, across batches, beyond a 1 ms window
    write_rpg_text(tmp_path, t, ev.x, ev.y, ev.p)
    with pytest.raises(
        ValueError, match=r"event 2500 \(line 2501\).*beyond the reorder window \(1000 us\)"
    ):
        run(
            tmp_path / "events.txt",
            IngestConfig(chunk_events=500, reorder_window_us=1000),
            width=W,
            height=H,
        )


def test_sorting_within_a_window_keeps_equal_timestamps_in_file_order(tmp_path):
    raw = [
        RawEvents(
            np.array([10, 30, 20]), np.array([0, 1, 2]), np.array([0, 0, 0]), np.array([1, 1, 1])
        ),
        RawEvents(
            np.array([20, 40]), np.array([3, 4]), np.array([0, 0]), np.array([0, 0]), start=3
        ),
    ]
    rep = ValidationReport()
    out = Events.concatenate(
        list(validate_stream(raw, tmp_path / "x", 8, 8, ValidationConfig(), rep))
    )
    assert out.t.tolist() == [10, 20, 20, 30, 40]
    assert out.x.tolist() == [0, 2, 3, 1, 4]
    assert rep.out_of_order == 2 and rep.max_step_back_us == 10


# --- coordinates -----------------------------------------------------------------------------------
def test_coordinates_outside_the_sensor(tmp_path, caplog):
    f = text_file(
        tmp_path, ["0.000001 1 1 1", "0.000002 64 3 0", "0.000003 5 47 1", "0.000004 2 48 1"]
    )
    with pytest.raises(
        ValueError,
        match=r"events\.txt: event at \(x=64, y=3\) is outside the 64x48 sensor at event 1 \(line 2\)",
    ):
        run(f, width=W, height=H)
    with caplog.at_level(logging.WARNING, logger="evdense"):
        res = run(f, IngestConfig(out_of_bounds="drop"), width=W, height=H)
    assert res.num_events == 2
    assert "dropped 2 events outside the 64x48 sensor" in caplog.text


def test_negative_coordinates_are_an_error(tmp_path):
    np.savez(
        tmp_path / "n.npz",
        t=np.array([1, 2, 3]),
        x=np.array([1, -2, 3]),
        y=np.array([0, 0, 0]),
        p=np.array([1, 0, 1]),
    )
    with pytest.raises(ValueError, match=r"n\.npz: negative coordinate \(x=-2, y=0\) at event 1"):
        run(tmp_path / "n.npz", width=W, height=H)


def test_sensor_size_inferred_with_a_warning(tmp_path, rng, caplog):
    ev = stream(rng)
    write_rpg_text(tmp_path, ev.t, ev.x, ev.y, ev.p)
    with caplog.at_level(logging.WARNING, logger="evdense"):
        res = run(tmp_path / "events.txt")
    assert (res.width, res.height) == (int(ev.x.max()) + 1, int(ev.y.max()) + 1)
    assert res.sensor_size_source == "inferred"
    assert "inferred" in caplog.text and "does not state its sensor size" in caplog.text


def test_config_size_overrides_the_file_with_a_warning(tmp_path, rng, caplog):
    ev = stream(rng)
    f = write_npz(tmp_path / "e.npz", ev.t, ev.x, ev.y, ev.p, 100, 100)
    with caplog.at_level(logging.WARNING, logger="evdense"):
        res = run(f, width=W, height=H)
    assert (res.width, res.height, res.sensor_size_source) == (W, H, "config")
    assert "the file says 100x100 but the config says 64x48" in caplog.text


# --- polarity --------------------------------------------------------------------------------------
def test_polarity_encodings(tmp_path):
    f = text_file(tmp_path, ["0.000001 1 1 -1", "0.000002 2 2 1"])
    assert run(f, width=W, height=H).validation["polarity_encoding"] == "-1/+1"
    with EventFile(tmp_path / "out.h5") as ef:
        assert ef.read().p.tolist() == [-1, 1]
    f = text_file(tmp_path, ["0.000001 1 1 0", "0.000002 2 2 1", "0.000003 2 2 2"])
    with pytest.raises(
        ValueError, match=r"polarity 2 at event 2 \(line 3\); expected 0/1 or -1/\+1"
    ):
        run(f, width=W, height=H)
    f = text_file(tmp_path, ["0.000001 1 1 0", "0.000002 2 2 1", "0.000003 2 2 -1"])
    with pytest.raises(
        ValueError, match=r"polarity -1 at event 2 \(line 3\) in a stream that uses 0/1"
    ):
        run(f, width=W, height=H)
    f = text_file(tmp_path, ["0.000001 1 1 -1", "0.000002 2 2 1", "0.000003 2 2 0"])
    with pytest.raises(
        ValueError,
        match=r"polarity 0 at event 2 \(line 3\) in a stream that uses -1/\+1 \(first -1 at event 0\)",
    ):
        run(f, width=W, height=H)


# --- malformed and truncated files -----------------------------------------------------------------
def test_text_malformed_line_is_an_error_naming_the_line(tmp_path):
    f = text_file(tmp_path, ["# header", "0.000001 1 1 0", "0.000002 2 x 1", "0.000003 2 2 1"])
    with pytest.raises(ValueError, match=r"events\.txt: line 3: cannot read an integer column"):
        run(f, width=W, height=H)
    f = text_file(tmp_path, ["0.000001 1 1 0 7"])
    with pytest.raises(ValueError, match=r"line 1: more than 4 columns"):
        run(f, width=W, height=H)


def test_text_truncated_last_line_is_dropped_with_a_warning(tmp_path, caplog):
    f = tmp_path / "events.txt"
    f.write_text("0.000001 1 1 0\n0.000002 2 2 1\n0.0000")
    with caplog.at_level(logging.WARNING, logger="evdense"):
        res = run(f, width=W, height=H)
    assert res.num_events == 2
    assert "line 3 is incomplete" in caplog.text and "truncated" in caplog.text


def test_truncated_dat_and_raw(tmp_path, rng, caplog):
    ev = stream(rng, 300)
    f = write_dat(tmp_path / "e.dat", ev.t, ev.x, ev.y, ev.p, W, H)
    f.write_bytes(f.read_bytes()[:-3])
    with caplog.at_level(logging.WARNING, logger="evdense"):
        res = run(f)
    assert res.num_events == 299
    assert "the last 5 bytes (from byte offset" in caplog.text
    g = write_evt3(tmp_path / "e.raw", ev.t, ev.x, ev.y, ev.p, W, H)
    g.write_bytes(g.read_bytes()[:-1])
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="evdense"):
        run(g)
    assert "the last 1 bytes" in caplog.text


def test_aedat4_truncated_and_corrupt(tmp_path, rng, caplog):
    ev = stream(rng, 3000)
    f = write_aedat4(tmp_path / "e.aedat4", ev.t, ev.x, ev.y, ev.p, W, H, packet_events=1000)
    data = f.read_bytes()
    f.write_bytes(data[:-100])
    with caplog.at_level(logging.WARNING, logger="evdense"):
        res = run(f)
    assert res.num_events == 2000
    assert "ends inside the packet at byte offset" in caplog.text
    bad = bytearray(data)
    bad[-200:-150] = b"\xff" * 50  # garble the LZ4 data of the last packet
    f.write_bytes(bytes(bad))
    (tmp_path / "out.h5").unlink()
    with pytest.raises(
        ValueError, match=r"e\.aedat4: packet of stream 0 at byte offset \d+ does not decode"
    ):
        run(f)
    assert not (tmp_path / "out.h5").exists()


def test_h5_fields_of_different_length(tmp_path, rng):
    ev = stream(rng, 100)
    f = write_e2vid_h5(tmp_path / "e.h5", ev.t, ev.x, ev.y, ev.p, W, H)
    with h5py.File(f, "a") as h:
        xs = h["events/xs"][:50]
        del h["events/xs"]
        h["events/xs"] = xs
    with pytest.raises(ValueError, match=r"e\.h5: event datasets differ in length"):
        open_recording(f)


def test_nan_timestamp(tmp_path, rng):
    ev = stream(rng, 100)
    f = write_e2vid_h5(tmp_path / "e.h5", ev.t, ev.x, ev.y, ev.p, W, H)
    with h5py.File(f, "a") as h:
        h["events/ts"][42] = np.nan
    with pytest.raises(ValueError, match=r"e\.h5: timestamp of event 42 is nan"):
        run(f)


def test_unknown_and_unsupported_formats(tmp_path):
    f = tmp_path / "x.bin"
    f.write_bytes(b"\x00\x01\x02garbage")
    with pytest.raises(ValueError, match=r"x\.bin: unrecognised recording format"):
        detect_format(f)
    g = tmp_path / "old.aedat"
    g.write_bytes(b"#!AER-DAT3.1\r\n")
    with pytest.raises(ValueError, match=r"AEDAT 3.1 files are not supported"):
        detect_format(g)
    r = tmp_path / "x.raw"
    r.write_bytes(b"% date 2020\n\x00\x00")
    with pytest.raises(ValueError, match=r"does not name its encoding"):
        detect_format(r)
