"""Windows of events: partition of the stream, times, caps, overlap, spec strings, the table file."""

from __future__ import annotations

import re

import numpy as np
import pytest

from evdense.events import windows as W
from evdense.events.container import EventFile, Events, write_events
from evdense.events.windows import (
    WINDOW_SPEC_REGEX,
    WindowConfig,
    compute_windows,
    make_windows,
    parse_window_spec,
    read_windows,
    window_spec,
)

WIDTH, HEIGHT = 40, 30


def _stream(rng: np.random.Generator, n: int) -> Events:
    """Sorted events with repeated timestamps, bursts and one long silent gap (exercises empty windows)."""
    dt = rng.choice([0, 0, 1, 3, 40], size=n).astype(np.int64)
    dt[n // 2] = 300_000  # a 0.3 s gap
    t = 1_000_000 + np.cumsum(dt)
    return Events(
        t,
        rng.integers(0, WIDTH, n),
        rng.integers(0, HEIGHT, n),
        rng.choice([-1, 1], n),
    )


@pytest.fixture
def stream(tmp_path, rng):
    ev = _stream(rng, 20_011)
    path = write_events(tmp_path / "events.h5", ev, WIDTH, HEIGHT)
    return path, ev


@pytest.fixture(params=[1 << 22, 997], ids=["one-block", "small-blocks"])
def read_block(request, monkeypatch):
    """Run each test with whole-file reads and with reads in blocks smaller than a window."""
    monkeypatch.setattr(W, "_READ_BLOCK", request.param)
    return request.param


def _assert_partition(w: W.Windows, n: int) -> None:
    assert w.i0[0] == 0
    assert w.i1[-1] == n
    np.testing.assert_array_equal(w.i0[1:], w.i1[:-1])  # no gap, no event twice
    assert np.all(w.count >= 0)
    assert w.count.sum() == n
    # each event index in exactly one window
    hits = np.zeros(n, np.int64)
    for a, b in zip(w.i0, w.i1, strict=True):
        hits[a:b] += 1
    assert np.all(hits == 1)


@pytest.mark.parametrize("num", [1000, 20_011, 25_000, 1, 7])
def test_event_count_windows_partition_the_stream(stream, read_block, num):
    path, ev = stream
    w = compute_windows(path, WindowConfig(mode="events", num_events=num))
    _assert_partition(w, len(ev))
    assert np.all(w.count[:-1] == num)
    assert 1 <= w.count[-1] <= num  # the last, partial window is kept
    assert len(w) == -(-len(ev) // num)
    np.testing.assert_array_equal(w.t_start_us, ev.t[w.i0])
    np.testing.assert_array_equal(w.t_end_us, ev.t[w.i1 - 1])


@pytest.mark.parametrize("num,max_ms", [(1000, 2.0), (1000, 1000.0), (3000, 0.05), (1, 0.001)])
def test_capped_windows_partition_and_respect_both_limits(stream, read_block, num, max_ms):
    path, ev = stream
    max_us = int(max_ms * 1000)
    w = compute_windows(
        path, WindowConfig(mode="events_capped", num_events=num, max_duration_ms=max_ms)
    )
    _assert_partition(w, len(ev))
    assert np.all(w.count <= num)
    t = ev.t
    assert np.all(t[w.i1 - 1] - t[w.i0] < max_us)
    # a window that ended early did so because the next event is past the cap
    early = (w.count < num) & (w.i1 < len(ev))
    assert np.all(t[w.i1[early]] - t[w.i0[early]] >= max_us)
    np.testing.assert_array_equal(w.t_end_us, t[w.i1 - 1])


def test_capped_windows_cap_in_the_gap(stream, read_block):
    path, ev = stream
    w = compute_windows(
        path, WindowConfig(mode="events_capped", num_events=5000, max_duration_ms=50)
    )
    # the 0.3 s silence ends a window early: some windows hold fewer than 5000 events mid-stream
    assert np.any(w.count[:-1] < 5000)


@pytest.mark.parametrize("dur_ms", [5.0, 0.5, 2000.0])
def test_time_windows_partition_and_cover_their_interval(stream, read_block, dur_ms):
    path, ev = stream
    w = compute_windows(path, WindowConfig(mode="time", duration_ms=dur_ms))
    _assert_partition(w, len(ev))
    dur = int(dur_ms * 1000)
    assert np.all(w.t_end_us - w.t_start_us == dur)
    assert w.t_start_us[0] == ev.t[0]
    np.testing.assert_array_equal(w.t_start_us[1:], w.t_end_us[:-1])
    assert w.t_end_us[-1] > ev.t[-1] >= w.t_start_us[-1]
    for k in range(len(w)):
        tk = ev.t[w.i0[k] : w.i1[k]]
        assert np.all((tk >= w.t_start_us[k]) & (tk < w.t_end_us[k]))
    if dur_ms < 300:
        assert np.any(w.count == 0)  # the silent gap leaves empty windows, kept in the table


def test_time_windows_match_index_at(stream):
    path, ev = stream
    w = compute_windows(path, WindowConfig(mode="time", duration_ms=3.3))
    with EventFile(path) as ef:
        for k in range(0, len(w), 7):
            assert w.i0[k] == ef.index_at(w.t_start_us[k])
            assert w.i1[k] == ef.index_at(w.t_end_us[k])


def test_overlapping_event_windows(stream, read_block):
    path, ev = stream
    n = len(ev)
    w = compute_windows(path, WindowConfig(mode="events", num_events=1000, overlap=0.5))
    assert np.all(np.diff(w.i0) == 500)
    assert w.i0[0] == 0 and w.i1[-1] == n
    assert np.all(w.count[:-1] == 1000)
    hits = np.zeros(n, np.int64)
    for a, b in zip(w.i0, w.i1, strict=True):
        hits[a:b] += 1
    assert hits.min() >= 1  # nothing lost
    assert hits[500:-1000].min() == 2 and hits.max() == 2  # each event in 1 / (1 - 0.5) windows
    assert w.i1[-2] < n  # no window after the first one that reaches the end


def test_overlapping_time_and_capped_windows_cover_everything(stream):
    path, ev = stream
    n = len(ev)
    for conf in (
        WindowConfig(mode="time", duration_ms=10, overlap=0.25),
        WindowConfig(mode="events_capped", num_events=800, max_duration_ms=4, overlap=0.5),
    ):
        w = compute_windows(path, conf)
        hits = np.zeros(n, np.int64)
        for a, b in zip(w.i0, w.i1, strict=True):
            hits[a:b] += 1
        assert hits.min() >= 1 and w.i1[-1] == n
        assert np.all(np.diff(w.i0) >= 0) and np.all(np.diff(w.i1) >= 0)
    w = compute_windows(path, WindowConfig(mode="time", duration_ms=10, overlap=0.25))
    assert np.all(np.diff(w.t_start_us) == 7500)


def test_single_timestamp_recording(tmp_path):
    ev = Events(np.full(10, 5), np.arange(10), np.zeros(10), np.ones(10))
    path = write_events(tmp_path / "e.h5", ev, 10, 1)
    for conf in (
        WindowConfig(mode="events", num_events=4),
        WindowConfig(mode="time", duration_ms=1),
        WindowConfig(mode="events_capped", num_events=4, max_duration_ms=1),
    ):
        _assert_partition(compute_windows(path, conf), 10)


def test_empty_recording_is_an_error(tmp_path):
    path = write_events(tmp_path / "e.h5", Events.empty(), 10, 10)
    with pytest.raises(ValueError, match="no events"):
        compute_windows(path, WindowConfig())


@pytest.mark.parametrize(
    "conf,spec",
    [
        (WindowConfig(), "n25000"),
        (WindowConfig(mode="time", duration_ms=50), "dt50ms"),
        (WindowConfig(mode="time", duration_ms=0.5), "dt0.5ms"),
        (
            WindowConfig(mode="events_capped", num_events=25000, max_duration_ms=100),
            "n25000-max100ms",
        ),
        (WindowConfig(num_events=15000, overlap=0.5), "n15000-ov0.5"),
        (WindowConfig(mode="time", duration_ms=2000, overlap=0.25), "dt2000ms-ov0.25"),
    ],
)
def test_window_spec_round_trip(conf, spec):
    assert window_spec(conf) == spec
    assert parse_window_spec(spec) == conf
    assert re.fullmatch(WINDOW_SPEC_REGEX, spec)
    assert window_spec({"mode": conf.mode, "num_events": conf.num_events}) == window_spec(
        WindowConfig(mode=conf.mode, num_events=conf.num_events)
    )


@pytest.mark.parametrize(
    "bad",
    [
        "n",
        "dt50",
        "n25000-ov1.5",
        "x100",
        "n100-max",
        "dt50.0ms",
        "n25000-ov0.50",
        "n025000",
        "dt050ms",
        "n0",
    ],
)
def test_bad_or_non_canonical_specs_are_refused(bad):
    with pytest.raises(ValueError):
        parse_window_spec(bad)
    assert not re.fullmatch(WINDOW_SPEC_REGEX, bad)  # Snakemake never matches them either


def test_bad_configs_are_refused():
    with pytest.raises(ValueError, match="mode"):
        WindowConfig(mode="frames")
    with pytest.raises(ValueError, match="overlap"):
        WindowConfig(overlap=1.0)
    with pytest.raises(ValueError, match="unknown"):
        WindowConfig.from_dict({"num_event": 5})


def test_make_windows_writes_a_table(stream, tmp_path):
    path, ev = stream
    out = make_windows(path, tmp_path / "windows_n1000.h5", WindowConfig(num_events=1000))
    w, attrs = read_windows(out)
    assert attrs["spec"] == "n1000"
    assert attrs["num_windows"] == len(w) == 21
    assert (attrs["width"], attrs["height"], attrs["num_events"]) == (WIDTH, HEIGHT, len(ev))
    _assert_partition(w, len(ev))
    assert not (tmp_path / "windows_n1000.h5.partial").exists()
