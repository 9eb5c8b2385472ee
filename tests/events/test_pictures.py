"""Event frames, the space-time plot and the per-dataset summary."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest

from evdense.events.container import Events, write_events
from evdense.events.pictures import (
    NEGATIVE_RGB,
    POSITIVE_RGB,
    event_frame,
    plot_space_time,
    polarity_counts,
    save_event_frame,
)
from evdense.events.summary import SummaryConfig, summarize_events
from evdense.events.windows import WindowConfig


def _hand_events() -> Events:
    # (x, y, p): pixel (0,0) two positive, (1,0) one negative, (2,1) one positive + one negative
    return Events(
        t=[0, 1, 2, 3, 4],
        x=[0, 0, 1, 2, 2],
        y=[0, 0, 0, 1, 1],
        p=[1, 1, -1, 1, -1],
    )


def test_polarity_counts_by_hand():
    c = polarity_counts(_hand_events(), 2, 3)
    exp = np.zeros((2, 2, 3), np.int64)
    exp[0, 0, 0] = 2
    exp[1, 0, 1] = 1
    exp[0, 1, 2] = exp[1, 1, 2] = 1
    np.testing.assert_array_equal(c, exp)


@pytest.mark.parametrize("background", ["white", "black"])
def test_event_frame_colours(background):
    img = event_frame(_hand_events(), 2, 3, background)
    assert img.shape == (2, 3, 3) and img.dtype == np.uint8
    bg = (255, 255, 255) if background == "white" else (0, 0, 0)
    assert tuple(img[0, 0]) == POSITIVE_RGB
    assert tuple(img[0, 1]) == NEGATIVE_RGB
    mix = np.round((np.array(POSITIVE_RGB) + np.array(NEGATIVE_RGB)) / 2)
    np.testing.assert_array_equal(img[1, 2], mix)
    for yx in [(0, 2), (1, 0), (1, 1)]:
        assert tuple(img[yx]) == bg


def test_event_frame_refuses_off_sensor_events_and_bad_background():
    with pytest.raises(ValueError, match="off the 2x2 sensor"):
        event_frame(_hand_events(), 2, 2)
    with pytest.raises(ValueError, match="background"):
        event_frame(_hand_events(), 2, 3, "grey")


def test_saved_frame_and_space_time_plot(tmp_path, rng):
    path = save_event_frame(tmp_path / "f.png", _hand_events(), 2, 3)
    np.testing.assert_array_equal(iio.imread(path), event_frame(_hand_events(), 2, 3))
    n = 50_000
    ev = Events(
        np.sort(rng.integers(0, 100_000, n)),
        rng.integers(0, 64, n),
        rng.integers(0, 48, n),
        rng.choice([-1, 1], n),
    )
    png = plot_space_time(tmp_path / "st.png", ev, 48, 64, max_events=2000)
    img = iio.imread(png)
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 300
    # both polarity colours are drawn
    rgb = img[..., :3].reshape(-1, 3).astype(int)
    for col in (POSITIVE_RGB, NEGATIVE_RGB):
        assert (np.abs(rgb - np.array(col)).sum(axis=1) < 60).sum() > 50


def test_summary_folder(tmp_path, rng):
    n, w, h = 40_000, 32, 24
    t = 2_000_000 + np.sort(rng.integers(0, 400_000, n))  # 0.4 s from t = 2 s
    p = np.where(rng.random(n) < 0.7, 1, -1)  # 70 % positive
    ev = Events(t, rng.integers(0, w, n), rng.integers(0, h, n), p)
    events = write_events(tmp_path / "ds" / "events" / "events.h5", ev, w, h)
    out = summarize_events(
        events,
        tmp_path / "ds" / "events" / "summary",
        SummaryConfig(rate_bin_ms=5, num_event_frames=3, spacetime_duration_ms=100),
        WindowConfig(num_events=5000),
    )
    s = json.loads((out / "summary.json").read_text())
    assert s["num_events"] == n
    assert s["num_positive"] == int((p > 0).sum())
    assert s["positive_fraction"] == pytest.approx((p > 0).mean())
    assert s["duration_s"] == pytest.approx((t[-1] - t[0]) * 1e-6)
    assert s["mean_rate_ev_per_s"] == pytest.approx(n / ((t[-1] - t[0]) * 1e-6))
    assert s["rate_bin_ms"] == 5
    assert s["peak_rate_ev_per_s"] >= s["mean_rate_ev_per_s"]
    assert s["events_per_pixel"] == pytest.approx(n / (w * h))
    assert s["windows"]["spec"] == "n5000" and s["windows"]["num_windows"] == 8
    assert [f["window"] for f in s["event_frames"]] == [0, 4, 7]
    for f in s["event_frames"]:
        img = iio.imread(out / f["file"])
        assert img.shape == (h, w, 3)
    # the space-time plot shows the middle 100 ms
    assert abs(s["spacetime"]["num_events"] - n / 4) < 0.1 * n
    for name in ("rate.png", "spacetime.png"):
        assert iio.imread(out / name).shape[0] > 100
    assert not (tmp_path / "ds" / "events" / "summary.partial").exists()
