"""The canonical event file: round trip, index and time-range reads, atomic writes, bad files."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from evdense.events.container import EventFile, Events, EventWriter, write_events


def random_events(
    rng: np.random.Generator, n: int, width: int = 64, height: int = 48, span_us: int = 50_000
) -> Events:
    t = np.sort(rng.integers(1_000_000, 1_000_000 + span_us, n))
    return Events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.choice([-1, 1], n))


def test_round_trip_in_several_appends(tmp_path, rng):
    ev = random_events(rng, 10_000)
    path = tmp_path / "ev.h5"
    with EventWriter(path, 64, 48, provenance={"source": "test"}, chunk_events=1024) as w:
        for s in range(0, len(ev), 3333):
            w.append(ev[s : s + 3333])
    with EventFile(path) as f:
        assert len(f) == 10_000
        assert (f.width, f.height) == (64, 48)
        back = f.read()
        for k in "txyp":
            np.testing.assert_array_equal(getattr(back, k), getattr(ev, k))
        assert f.attrs["provenance"] == {"source": "test"}
        assert f.attrs["time_unit"] == "us"
        assert f.t_start_us == ev.t[0] and f.t_end_us == ev.t[-1]


@pytest.mark.parametrize(
    "t_query", [0, 1_000_000, 1_000_001, 1_012_345, 1_049_999, 1_050_000, 2_000_000]
)
def test_index_at_matches_searchsorted(tmp_path, rng, t_query):
    ev = random_events(rng, 5_000)
    path = write_events(tmp_path / "ev.h5", ev, 64, 48)
    with EventFile(path) as f:
        assert f.index_at(t_query) == np.searchsorted(ev.t, t_query, side="left")


def test_read_time_range_and_chunks(tmp_path, rng):
    ev = random_events(rng, 20_000)
    path = write_events(tmp_path / "ev.h5", ev, 64, 48)
    with EventFile(path) as f:
        sub = f.read_time(1_010_000, 1_020_000)
        mask = (ev.t >= 1_010_000) & (ev.t < 1_020_000)
        np.testing.assert_array_equal(sub.t, ev.t[mask])
        chunks = list(f.iter_chunks(3000))
        assert sum(len(c) for c in chunks) == 20_000
        np.testing.assert_array_equal(Events.concatenate(chunks).x, ev.x)


def test_failed_write_leaves_no_file(tmp_path, rng):
    path = tmp_path / "ev.h5"
    ev = random_events(rng, 100)
    with pytest.raises(RuntimeError), EventWriter(path, 64, 48) as w:
        w.append(ev)
        raise RuntimeError("simulated crash")
    assert not path.exists()
    assert not list(tmp_path.iterdir())


def test_writer_rejects_bad_events(tmp_path):
    with EventWriter(tmp_path / "a.h5", 10, 10) as w:
        with pytest.raises(ValueError, match="non-decreasing"):
            w.append(Events([5, 3], [0, 0], [0, 0], [1, 1]))
        with pytest.raises(ValueError, match="outside the 10x10 sensor"):
            w.append(Events([1, 2], [0, 10], [0, 0], [1, 1]))
        with pytest.raises(ValueError, match="polarity"):
            w.append(Events([1, 2], [0, 1], [0, 0], [1, 0]))


def test_foreign_hdf5_is_refused_with_its_name(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.arange(3)
    with pytest.raises(ValueError, match="other.h5: not an evdense event file"):
        EventFile(path)
