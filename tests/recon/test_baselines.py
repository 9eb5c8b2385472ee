"""Classical baselines: direct integration and the high-pass / complementary filter, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from evdense.events.container import Events
from evdense.recon.baselines import LogIntensityFilter


def _ev(t, x, y, p) -> Events:
    return Events(np.array(t), np.array(x), np.array(y), np.array(p))


def test_integration_of_hand_made_events():
    # 4x3 sensor; pixel (x=1, y=0): +,+,-; pixel (x=3, y=2): -,-; pixel (x=0, y=1): +
    ev = _ev(
        [10, 20, 30, 40, 50, 60], [1, 3, 1, 0, 1, 3], [0, 2, 0, 1, 0, 2], [1, -1, 1, 1, -1, -1]
    )
    f = LogIntensityFilter(3, 4, cutoff_rad_s=0.0, contrast_on=0.3, contrast_off=0.2, t_us=0)
    img = f.advance(ev, 100).copy()
    expected = np.zeros((3, 4))
    expected[0, 1] = 0.3 + 0.3 - 0.2
    expected[2, 3] = -0.2 - 0.2
    expected[1, 0] = 0.3
    np.testing.assert_allclose(img, expected, atol=1e-12)
    # no events, no leak: nothing changes
    np.testing.assert_allclose(f.advance(Events.empty(), 10_000), expected, atol=1e-12)


def test_high_pass_decays_as_the_formula_says():
    alpha = 4.0  # rad/s
    f = LogIntensityFilter(2, 2, cutoff_rad_s=alpha, contrast_on=0.25, contrast_off=0.25, t_us=0)
    f.advance(_ev([100_000], [1], [0], [1]), 100_000)  # one event at t = 0.1 s
    assert f.log_image[0, 1] == pytest.approx(0.25)
    for t_s in (0.2, 0.35, 1.1):
        img = f.advance(Events.empty(), int(t_s * 1e6))
        assert img[0, 1] == pytest.approx(0.25 * np.exp(-alpha * (t_s - 0.1)), rel=1e-12)
        assert img[0, 0] == img[1, 0] == img[1, 1] == 0.0
    # after the 1/alpha time constant the contribution has fallen to 1/e
    g = LogIntensityFilter(1, 1, cutoff_rad_s=alpha, t_us=0)
    g.advance(_ev([0], [0], [0], [1]), 0)
    assert g.advance(Events.empty(), int(1e6 / alpha))[0, 0] == pytest.approx(0.2 / np.e)


def test_window_evaluation_equals_event_by_event_recursion(rng):
    h, w, n, alpha = 5, 6, 2000, 7.0
    t = np.sort(rng.integers(0, 500_000, n))
    x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    p = rng.choice([-1, 1], n)
    # the recursion of the paper: decay since the pixel's last update, then add the event
    L, last = np.zeros((h, w)), np.zeros((h, w))
    for tk, xk, yk, pk in zip(t, x, y, p, strict=True):
        L[yk, xk] = L[yk, xk] * np.exp(-alpha * (tk - last[yk, xk]) * 1e-6) + 0.2 * pk
        last[yk, xk] = tk
    t_end = 600_000
    L *= np.exp(-alpha * (t_end - last) * 1e-6)
    # windows of uneven size, evaluated in one bincount each
    f = LogIntensityFilter(h, w, cutoff_rad_s=alpha, t_us=0)
    cuts = [0, 3, 700, 701, 1500, n]
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        f.advance(_ev(t[a:b], x[a:b], y[a:b], p[a:b]), int(t[b - 1]))
    np.testing.assert_allclose(f.advance(Events.empty(), t_end), L, rtol=1e-10, atol=1e-12)


def test_complementary_filter_converges_to_the_reference():
    alpha = 2.0
    f = LogIntensityFilter(2, 3, cutoff_rad_s=alpha, t_us=0)
    f.advance(_ev([0, 0], [0, 2], [0, 1], [1, -1]), 0)
    start = f.log_image.copy()
    ref = np.log(np.array([[0.2, 0.5, 0.9], [0.1, 0.3, 1.0]]))
    f.set_reference(ref)
    img = f.advance(Events.empty(), 500_000)
    np.testing.assert_allclose(img, ref + (start - ref) * np.exp(-alpha * 0.5), rtol=1e-12)
    with pytest.raises(ValueError, match="shape"):
        f.set_reference(np.zeros((3, 2)))


def test_bad_inputs_are_refused():
    f = LogIntensityFilter(2, 2, t_us=1000)
    with pytest.raises(ValueError, match="back in time"):
        f.advance(Events.empty(), 10)
    with pytest.raises(ValueError, match="outside"):
        f.advance(_ev([5], [0], [0], [1]), 2000)
    with pytest.raises(ValueError, match="cutoff"):
        LogIntensityFilter(2, 2, cutoff_rad_s=-1)
