"""The conventional frame camera on exact, hand-built radiance."""

from __future__ import annotations

import json
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from evdense.sim.conventional import (
    ConventionalCameraConfig,
    expose,
    frame_times,
    integrate_exposure,
    integrate_exposure_adaptive,
    meter,
    simulate_frames,
    subrender_times,
)

REPO = Path(__file__).resolve().parents[2]


def moving_edge(h: int, w: int, speed_px_s: float, x0: float = 5.0):
    """Dark (0.1) left of a vertical edge at x0 + speed * t, bright (1.0) right of it, anti-aliased."""
    xx = np.arange(w, dtype=np.float64)[None, :].repeat(h, 0)

    def radiance(t):
        cover = np.clip(xx + 0.5 - (x0 + speed_px_s * t), 0.0, 1.0)
        return 0.1 + 0.9 * cover

    return radiance


def read_frames(out: Path) -> tuple[list[np.ndarray], np.ndarray]:
    lines = (out / "frames" / "timestamps.txt").read_text().split("\n")
    ts = np.array([[float(v) for v in ln.split()] for ln in lines if ln])
    frames = [iio.imread(out / "frames" / f"{int(i):06d}.png") for i in ts[:, 0]]
    return frames, ts


def test_static_frame_equals_ground_truth_within_quantisation(tmp_path, rng):
    gt = rng.uniform(0.05, 1.0, size=(12, 16))
    conf = ConventionalCameraConfig(fps=10.0, exposure_s=0.02)
    out = tmp_path / "conventional"
    recs = simulate_frames(lambda t: gt, 0.35, conf, None, out)
    frames, ts = read_frames(out)
    assert len(frames) == 4 and all(r.subframes == 3 for r in recs)
    # Timestamps are the middle of each exposure.
    np.testing.assert_allclose(ts[:, 1], np.arange(4) * 0.1 + 0.01)
    for f, r in zip(frames, recs, strict=True):
        assert f.dtype == np.uint8 and f.shape == gt.shape
        # Back to radiance: within half a grey level of the ground truth.
        back = f.astype(np.float64) / 255.0 * conf.full_well_e / r.scale
        lsb = conf.full_well_e / 255.0 / r.scale
        assert np.max(np.abs(back - gt)) <= 0.5 * lsb + 1e-12
    # Auto-exposure put the median at the target level.
    assert np.median(frames[0]) == pytest.approx(conf.target_level * 255, abs=1)
    settings = json.loads((out / "settings.json").read_text())
    assert settings["num_frames"] == 4 and settings["camera"]["fps"] == 10.0


def test_radiance_above_full_well_reads_255(rng):
    conf = ConventionalCameraConfig(auto_exposure="off", sensitivity=1000.0, exposure_s=0.01)
    scale = conf.sensitivity * conf.exposure  # 10 electrons per radiance unit
    rad = np.array([[conf.full_well_e / scale * 0.5, conf.full_well_e / scale, 5000.0, 1e9]])
    exact = expose(rad, scale, conf, None)
    np.testing.assert_array_equal(exact, [[128, 255, 255, 255]])
    noisy = expose(rad, scale, conf, rng)
    np.testing.assert_array_equal(
        noisy[0, 2:], 255
    )  # far above the full well stays saturated with noise


def test_hdr_scene_saturates_the_lamp_and_keeps_the_room(tmp_path):
    room = np.full((20, 20), 0.2)
    room[:, :10] = 0.1
    room[5:8, 5:8] = 0.2 * 1000.0  # a lamp 1000 times brighter than the walls
    conf = ConventionalCameraConfig(fps=10.0)
    simulate_frames(lambda t: room, 0.1, conf, np.random.default_rng(0), tmp_path / "c")
    (frame,), _ = read_frames(tmp_path / "c")
    assert np.all(frame[5:8, 5:8] == 255)
    walls = frame[10:, 10:]
    assert 80 < walls.mean() < 130 and walls.max() < 255
    # The darker half is still resolved (about half the grey level), not crushed.
    assert 0.4 < frame[10:, :5].mean() / walls.mean() < 0.6


def test_blurred_frame_is_the_mean_of_its_subrenders():
    f = moving_edge(6, 40, speed_px_s=2000.0)
    conf = ConventionalCameraConfig(
        subframes=8, exposure_s=0.01, auto_exposure="off", sensitivity=1e6
    )
    t = subrender_times(0.0, conf.exposure, 8)
    np.testing.assert_allclose(t, (np.arange(8) + 0.5) * 0.01 / 8)
    mean = integrate_exposure(f, 0.0, conf.exposure, 8)
    np.testing.assert_allclose(mean, np.mean([f(ti) for ti in t], axis=0))
    # The edge moved 20 px during the exposure: a ramp, not a step.
    row = mean[0]
    assert np.sum((row > 0.15) & (row < 0.95)) >= 15
    img = expose(mean, conf.sensitivity * conf.exposure, conf, None)
    np.testing.assert_array_equal(
        img, expose(np.mean([f(ti) for ti in t], axis=0), 1e4, conf, None)
    )


def test_adaptive_subframes_follow_the_motion():
    def adaptive(speed):
        f = moving_edge(4, 40, speed)
        mean, n = integrate_exposure_adaptive(f, 0.0, 0.01, tolerance=0.02, max_subframes=81)
        np.testing.assert_allclose(mean, integrate_exposure(f, 0.0, 0.01, n))
        return n

    assert adaptive(0.0) == 3  # one refinement shows nothing changes
    slow, fast = adaptive(100.0), adaptive(2000.0)  # 1 px and 20 px per exposure
    assert slow < fast
    assert fast == 81


def test_shot_and_read_noise_statistics():
    conf = ConventionalCameraConfig(full_well_e=1000.0, read_noise_e=5.0, shot_noise=True)
    rad = np.full((200, 200), 400.0)
    img = expose(rad, 1.0, conf, np.random.default_rng(0)).astype(np.float64)
    e = img / 255.0 * conf.full_well_e
    assert e.mean() == pytest.approx(400.0, rel=0.01)
    # Variance: Poisson (400) + read (25) + quantisation ((1000/255)^2 / 12).
    expected_var = 400 + 25 + (1000 / 255) ** 2 / 12
    assert e.var() == pytest.approx(expected_var, rel=0.05)


def test_frame_times_and_exposure_fraction():
    conf = ConventionalCameraConfig(fps=20.0, exposure_fraction=0.5)
    assert conf.exposure == pytest.approx(0.025)
    np.testing.assert_allclose(frame_times(1.0, conf), np.arange(20) * 0.05)
    np.testing.assert_allclose(frame_times(0.124, conf), [0.0, 0.05])


def test_auto_exposure_once_and_smoothing(tmp_path):
    def brightening(t):
        return np.full((4, 4), 1.0 if t < 0.2 else 4.0)

    for mode, expect_last in (("once", 0.25), ("per_frame", None)):
        conf = ConventionalCameraConfig(fps=10.0, auto_exposure=mode, ae_smoothing=0.5)
        recs = simulate_frames(brightening, 0.5, conf, None, tmp_path / mode)
        frames, _ = read_frames(tmp_path / mode)
        if expect_last is None:
            # Smoothed: scale halves per frame in log space towards the new metering.
            assert recs[1].scale == pytest.approx(recs[0].scale)
            assert recs[2].scale == pytest.approx(recs[0].scale / 2)
            assert recs[3].scale == pytest.approx(recs[0].scale / 2**1.5)
        else:
            assert all(r.scale == recs[0].scale for r in recs)
            assert np.all(frames[-1] == 255)


def test_output_replaces_old_folder_atomically(tmp_path, rng):
    out = tmp_path / "conventional"
    (out / "frames").mkdir(parents=True)
    (out / "frames" / "999999.png").write_bytes(b"stale")
    gt = rng.uniform(0.1, 1.0, (5, 5))
    simulate_frames(lambda t: gt, 0.2, ConventionalCameraConfig(), None, out)
    assert sorted(p.name for p in (out / "frames").iterdir()) == [
        "000000.png",
        "000001.png",
        "000002.png",
        "000003.png",
        "timestamps.txt",
    ]
    assert not (tmp_path / "conventional.partial").exists()

    def broken(t):
        if t > 0.05:
            raise RuntimeError("renderer failed")
        return gt

    with pytest.raises(RuntimeError):
        simulate_frames(broken, 0.2, ConventionalCameraConfig(), None, tmp_path / "other")
    assert not (tmp_path / "other").exists() and not (tmp_path / "other.partial").exists()


def test_meter_maps_percentile_to_target(rng):
    rad = rng.uniform(0.0, 2.0, (50, 50))
    conf = ConventionalCameraConfig(metering_percentile=50.0, target_level=0.4)
    assert np.median(rad) * meter(rad, conf) == pytest.approx(0.4 * conf.full_well_e)


def test_bad_config_raises():
    with pytest.raises(ValueError, match="exposure_s"):
        ConventionalCameraConfig.from_dict({"fps": 50.0, "exposure_s": 0.05})
    with pytest.raises(ValueError, match="auto_exposure"):
        ConventionalCameraConfig.from_dict({"auto_exposure": "sometimes"})
    with pytest.raises(ValueError, match="unknown keys"):
        ConventionalCameraConfig.from_dict({"iso": 100})


def test_simulate_conventional_through_the_real_renderer(tmp_path):
    pytest.importorskip("evdense.sim.presets")
    from evdense.sim.simulate import simulate_conventional

    cam = {"width": 64, "height": 48, "fx": 46.0, "fy": 46.0, "cx": 31.5, "cy": 23.5}
    dataset = {"scene": "room", "speed": 4.0, "duration": 0.6, "seed": 0}  # 0.15 s of recording
    sim = {"render": {"camera": cam}, "conventional_camera": {"fps": 20.0, "max_subframes": 9}}
    out = simulate_conventional(dataset, sim, tmp_path / "conventional")
    frames, ts = read_frames(out)
    assert len(frames) == 3
    np.testing.assert_allclose(ts[:, 1], [0.005, 0.055, 0.105])
    assert all(f.shape == (48, 64) and f.dtype == np.uint8 for f in frames)
    assert all(20 < f.mean() < 200 for f in frames)  # auto-exposed, not black or white
    settings = json.loads((out / "settings.json").read_text())
    assert settings["provenance"]["scene"] == "room" and settings["sensor"]["width"] == 64
