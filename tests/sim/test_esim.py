"""The ESIM-style event camera on exact, hand-built radiance (plus one run through the real renderer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evdense.events.container import EventFile, Events
from evdense.sim.esim import (
    EventCameraConfig,
    EventSimulator,
    PhotoreceptorFilter,
    log_intensity,
    simulate_event_stream,
    write_event_stream,
)

REPO = Path(__file__).resolve().parents[2]


def ideal(**kw) -> EventCameraConfig:
    """No mismatch, no noise, no refractory period unless asked."""
    base = dict(contrast_sigma=0.0, noise_rate_hz=0.0, hot_pixel_fraction=0.0, refractory_us=0.0)
    base.update(kw)
    return EventCameraConfig(**base)


def run(radiance_at, t0, t1, conf, seed=0) -> tuple[Events, object]:
    parts: list[Events] = []
    stats = simulate_event_stream(
        radiance_at, t0, t1, conf, np.random.default_rng(seed), parts.append
    )
    return Events.concatenate(parts), stats


@pytest.mark.parametrize("rate", [12.0, -12.0])
def test_single_pixel_ramp_gives_every_crossing_at_its_time(rate):
    conf = ideal(contrast_pos=0.2, contrast_neg=0.3)
    eps = conf.log_eps
    # log(R + eps) = 1 + rate * t exactly.
    ev, _ = run(lambda t: np.full((1, 1), np.exp(1.0 + rate * t) - eps), 0.0, 0.49, conf)
    c = conf.contrast_pos if rate > 0 else conf.contrast_neg
    n_expected = int(np.floor(abs(rate) * 0.49 / c))
    assert len(ev) == n_expected
    assert np.all(ev.p == np.sign(rate))
    expected_t = np.arange(1, n_expected + 1) * c / abs(rate) * 1e6
    np.testing.assert_allclose(ev.t, expected_t, atol=1.0)  # microsecond rounding only


def test_limited_bandwidth_delays_a_ramp_by_tau_and_dim_pixels_more():
    """With ``cutoff_hz`` the crossings of a log-linear ramp come ``tau = 1 / (2 pi f)`` late once
    the filter has settled (its output trails a ramp by slope x tau); a pixel 1,000 times dimmer
    runs at the floor of the cut-off, so it lags ten times more."""
    rate, c, f = 12.0, 0.2, 100.0
    conf = ideal(contrast_pos=c, contrast_neg=c, cutoff_hz=f, cutoff_floor=0.1)
    eps = conf.log_eps

    def radiance(t: float) -> np.ndarray:
        bright = np.exp(rate * t) - eps  # starts at the reference radiance (about 1)
        return np.array([[bright, 1e-3 * (bright + eps) - eps]])

    ev, _ = run(radiance, 0.0, 0.49, conf)
    tau = 1.0 / (2 * np.pi * f)
    ideal_t = np.arange(1, 30) * c / rate
    bright = ev.t[ev.x == 0] * 1e-6
    np.testing.assert_allclose(bright, (ideal_t + tau)[: len(bright)], atol=2e-6)
    assert len(bright) == int(np.floor((0.49 - tau) * rate / c))
    dim = ev.t[ev.x == 1] * 1e-6
    early = dim[(dim > 0.15) & (dim < 0.35)]  # settled, and still below 10 % of the reference
    lag = early - ideal_t[np.searchsorted(ideal_t, early) - 1]
    np.testing.assert_allclose(lag, 10 * tau, atol=2e-6)
    # The filter alone: a constant input after a step decays as exp(-t / tau), step size free.
    lp = PhotoreceptorFilter(np.zeros((1, 1)), conf)
    y_fine = [lp.advance(np.ones((1, 1)), 1e-4)[0, 0] for _ in range(50)]
    lp2 = PhotoreceptorFilter(np.zeros((1, 1)), conf)
    lp2.advance(np.ones((1, 1)), 1e-4)  # the same jump in the first step, then one long step
    y_long = lp2.advance(np.ones((1, 1)), 49e-4)[0, 0]
    np.testing.assert_allclose(y_long, y_fine[-1], rtol=1e-12)


def test_multiple_crossings_in_one_step_are_interpolated():
    conf = ideal(contrast_pos=0.25)
    sim = EventSimulator(1, 2, conf, np.random.default_rng(0))
    sim.reset(np.zeros((1, 2)), 0.0)
    # Pixel 0 rises by 1.1 (4 crossings), pixel 1 by 0.6 (2 crossings), over 1 ms.
    ev = sim.step(np.array([[1.1, 0.6]]), 1e-3)
    assert len(ev) == 6 and np.all(ev.p == 1)
    t0 = ev.t[ev.x == 0]
    t1 = ev.t[ev.x == 1]
    np.testing.assert_allclose(t0, np.array([0.25, 0.5, 0.75, 1.0]) / 1.1 * 1e3, atol=0.5)
    np.testing.assert_allclose(t1, np.array([0.25, 0.5]) / 0.6 * 1e3, atol=0.5)
    assert np.all(np.diff(ev.t) >= 0)
    # Reference moved by C per crossing.
    np.testing.assert_allclose(sim.reference, [[1.0, 0.5]])
    # Going back down: crossings of ref - k * C- only.
    ev2 = sim.step(np.array([[0.2, 0.5]]), 2e-3)
    assert len(ev2) == 3 and np.all(ev2.p == -1) and np.all(ev2.x == 0)


def test_refractory_period_suppresses_but_reference_keeps_up():
    conf = ideal(contrast_pos=0.1, refractory_us=100.0)
    rate = 0.1 / 30e-6  # a crossing every 30 us
    T = 0.002
    eps = conf.log_eps

    def radiance(t):
        tt = min(t, T)  # ramp, then constant
        return np.full((1, 1), np.exp(rate * tt) - eps)

    ev, stats = run(radiance, 0.0, 0.004, conf)
    crossings = np.round(np.arange(1, int(rate * T / 0.1 + 1e-6) + 1) * 30.0).astype(int)
    # Greedy reference: emit a crossing when >= 100 us after the previous emitted one.
    expected, last = [], -(10**9)
    for tc in crossings:
        if tc - last >= 100:
            expected.append(tc)
            last = tc
    np.testing.assert_array_equal(ev.t, expected)
    assert np.all(np.diff(ev.t) >= 100)
    assert stats.suppressed == len(crossings) - len(expected)
    # No burst after the ramp ends: the reference advanced on suppressed crossings too.
    assert ev.t.max() <= T * 1e6 + 1


def test_static_scene_without_noise_gives_no_events(rng):
    img = rng.uniform(0.05, 2.0, size=(20, 30))
    ev, stats = run(lambda t: img, 0.0, 1.0, ideal())
    assert len(ev) == 0
    assert stats.max_step_s == pytest.approx(ideal().max_step_us * 1e-6)


def test_static_scene_noise_count_matches_rate(rng):
    img = rng.uniform(0.05, 2.0, size=(40, 50))
    conf = EventCameraConfig(noise_rate_hz=2.0, hot_pixel_fraction=0.0)
    ev, stats = run(lambda t: img, 0.0, 2.0, conf)
    expected = 2.0 * img.size * 2.0
    assert stats.signal_events == 0
    assert abs(len(ev) - expected) < 5 * np.sqrt(expected)
    assert np.all(np.diff(ev.t) >= 0)
    assert set(np.unique(ev.p)) == {-1, 1}
    assert abs(np.mean(ev.p == 1) - 0.5) < 0.05


def test_hot_pixels_fire_at_their_rate(rng):
    img = np.ones((50, 40))
    conf = EventCameraConfig(noise_rate_hz=0.0, hot_pixel_fraction=0.01, hot_pixel_rate_hz=50.0)
    ev, _ = run(lambda t: img, 0.0, 1.0, conf, seed=3)
    pix = ev.y.astype(int) * 40 + ev.x
    hot = np.unique(pix)
    assert len(hot) <= 20  # 1 % of 2000 pixels
    expected = 20 * 50.0
    assert abs(len(ev) - expected) < 5 * np.sqrt(expected)


def test_threshold_mismatch_and_clipping():
    conf = EventCameraConfig(
        contrast_pos=0.2, contrast_neg=0.3, contrast_sigma=0.05, contrast_min=0.15
    )
    sim = EventSimulator(200, 200, conf, np.random.default_rng(1))
    assert sim.c_pos.min() >= 0.15 and sim.c_neg.min() >= 0.15
    assert np.mean(sim.c_neg) == pytest.approx(0.3, abs=0.005)
    assert np.std(sim.c_neg) == pytest.approx(0.05, abs=0.005)


def moving_texture(h: int, w: int, speed_px_s: float):
    """A smooth 2D texture translating horizontally at ``speed_px_s`` pixels per second."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)

    def radiance(t):
        x = xx - speed_px_s * t
        return (
            0.3 + 0.25 * np.sin(x / 2.3) * np.cos(yy / 3.1) + 0.2 * np.sin(x / 5.7 + yy / 4.0) + 0.3
        )

    return radiance


def test_halving_the_step_changes_little():
    f = moving_texture(24, 32, 300.0)
    conf = ideal()
    a, sa = run(f, 0.0, 0.1, conf)
    b, sb = run(f, 0.0, 0.1, ideal(step_subdivisions=2))
    assert sb.renders > 1.8 * sa.renders
    assert len(a) > 1000
    assert abs(len(a) - len(b)) / len(b) < 0.05
    ma = np.bincount(a.y.astype(int) * 32 + a.x, minlength=24 * 32)
    mb = np.bincount(b.y.astype(int) * 32 + b.x, minlength=24 * 32)
    assert np.abs(ma - mb).sum() / mb.sum() < 0.05


def test_adaptive_step_bounds_the_change_between_renders():
    f = moving_texture(24, 32, 500.0)
    conf = ideal()
    times: list[float] = []
    simulate_event_stream(
        f, 0.0, 0.05, conf, np.random.default_rng(0), lambda e: None, step_log=times
    )
    ts = np.concatenate([[0.0], times])
    assert ts[-1] == pytest.approx(0.05)
    tol = conf.step_tolerance * conf.contrast_pos
    for t0, t1 in zip(ts[:-1], ts[1:], strict=True):
        d = np.abs(log_intensity(f(t1), conf.log_eps) - log_intensity(f(t0), conf.log_eps))
        assert (
            np.percentile(d, conf.step_percentile) <= tol + 1e-9
            or t1 - t0 <= conf.min_step_us * 1e-6 + 1e-12
        )


def test_event_file_holds_events_and_settings(tmp_path):
    f = moving_texture(16, 20, 200.0)
    conf = EventCameraConfig(chunk_events=500)
    out = tmp_path / "events.h5"
    stats = write_event_stream(
        f, 0.0, 0.2, conf, np.random.default_rng(0), out, provenance={"test": 1}
    )
    with EventFile(out) as ef:
        assert (ef.width, ef.height) == (20, 16)
        assert ef.num_events == stats.num_events > 1000
        ev = ef.read()
        assert np.all(np.diff(ev.t) >= 0)
        assert ev.t.min() >= 0 and ev.t.max() <= 200_000
        attrs = ef.attrs
    assert attrs["event_camera"]["contrast_pos"] == conf.contrast_pos
    assert attrs["simulation_stats"]["renders"] == stats.renders
    assert not (tmp_path / "events.h5.partial").exists()


def test_failed_run_leaves_no_file(tmp_path):
    def broken(t):
        if t > 0.01:
            raise RuntimeError("renderer failed")
        return np.ones((4, 4))

    with pytest.raises(RuntimeError):
        write_event_stream(
            broken, 0.0, 0.1, EventCameraConfig(), np.random.default_rng(0), tmp_path / "e.h5"
        )
    assert list(tmp_path.iterdir()) == []


def test_bad_config_and_input_raise():
    with pytest.raises(ValueError, match="contrast_pos"):
        EventCameraConfig.from_dict({"contrast_pos": 0.0})
    with pytest.raises(ValueError, match="unknown keys"):
        EventCameraConfig.from_dict({"threshold": 0.2})
    with pytest.raises(ValueError, match="finite"):
        log_intensity(np.array([[np.nan]]), 1e-3)


SMALL_CAMERA = {"width": 64, "height": 48, "fx": 46.0, "fy": 46.0, "cx": 31.5, "cy": 23.5}


def test_simulate_events_through_the_real_renderer(tmp_path):
    pytest.importorskip("evdense.sim.presets")
    from evdense.sim.simulate import simulate_events

    dataset = {"scene": "room", "speed": 4.0, "duration": 0.4, "seed": 3}  # 0.1 s of recording
    sim = {
        "render": {"camera": SMALL_CAMERA},
        "event_camera": {"noise_rate_hz": 0.0, "hot_pixel_fraction": 0.0},
    }
    out = simulate_events(dataset, sim, tmp_path / "events" / "events.h5")
    with EventFile(out) as ef:
        assert (ef.width, ef.height) == (64, 48)
        assert ef.num_events > 500
        ev = ef.read()
        attrs = ef.attrs
    assert np.all(np.diff(ev.t) >= 0) and 0 <= ev.t.min() and ev.t.max() <= 100_000
    assert attrs["scene"] == "room" and attrs["event_camera"]["noise_rate_hz"] == 0.0
    assert attrs["provenance"]["dataset"]["seed"] == 3
    # Both polarities, spread over the sensor (the whole room moves past the camera).
    assert set(np.unique(ev.p)) == {-1, 1}
    assert len(np.unique(ev.y.astype(int) * 64 + ev.x)) > 0.3 * 64 * 48
    # The same seed gives the same events.
    out2 = simulate_events(dataset, sim, tmp_path / "again.h5")
    with EventFile(out2) as ef:
        np.testing.assert_array_equal(ef.read().t, ev.t)
