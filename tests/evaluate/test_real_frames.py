"""Real-frame evaluation (EVREAL-style) and the planar training generator's textures."""

from __future__ import annotations

import numpy as np
import pytest

from evdense.evaluate.real_frames import (
    RealClip,
    evaluate_clip,
    read_anchor_clips,
    read_ecd_clip,
    read_rotation_clip,
    shifted_metrics,
)
from evdense.training.planar import (
    HELDOUT_PICTURES,
    TEXTURE_KINDS,
    TRAIN_PICTURES,
    PlanarScene,
    _mosaic_texture,
    load_picture,
    random_texture,
)


def _scene(rng, h=60, w=80):
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(rng.random((h, w)), 2.0)


def test_shifted_metrics_finds_the_displacement(rng):
    img = _scene(rng)
    moved = np.roll(img, (3, -2), axis=(0, 1))  # content 3 rows down, 2 columns left
    s = shifted_metrics(moved, img, max_shift=5)
    assert (s["dx"], s["dy"]) == (-2, 3)
    assert s["ssim"] == pytest.approx(1.0) and s["mse"] == pytest.approx(0.0)
    # a gain and an offset do not count; an unrelated image scores low
    assert shifted_metrics(0.3 * moved + 0.5, img, 5)["ssim"] == pytest.approx(1.0)
    assert shifted_metrics(_scene(rng), img, 5)["ssim"] < 0.5


def test_evaluate_clip_picks_the_window_nearest_each_frame(rng):
    n = 200
    t = np.arange(1000, dtype=np.int64) * 10  # 1000 events over 10 ms, windows of 2 ms
    x, y = rng.integers(0, 40, 1000), rng.integers(0, 30, 1000)
    p = np.where(rng.random(1000) < 0.5, 1.0, -1.0)
    ref = _scene(rng, 30, 40)
    clip = RealClip("toy", t, x, y, p, 40, 30, [(-50_000, ref), (4_100, ref), (None, ref)])
    calls = []

    def make():
        def rec(v):
            calls.append(v.shape)
            return ref + 0.01 * len(calls)

        return rec

    rows = evaluate_clip(clip, make, n, max_shift=3)
    assert len(calls) == 5 and calls[0] == (5, 30, 40)
    # the frame long before the events is skipped; 4.1 ms is nearest window 1 (ends at 3.99 ms)
    assert [r["frame"] for r in rows] == [1, 2]
    assert rows[0]["window"] == 1 and rows[1]["window"] == 4 and rows[1]["dt_ms"] is None
    assert all(r["ssim"] == pytest.approx(1.0) for r in rows)


def test_real_ecd_clips_read(anchors):
    slider = read_ecd_clip(anchors / "data" / "ecd_slider_depth")
    assert len(slider.t) == 50_000 and len(slider.frames) == 87
    assert slider.frames[0][1].shape == (180, 240) and np.all(np.diff(slider.t) >= 0)
    rot = read_rotation_clip(anchors / "data" / "ecd_rotation" / "shapes")
    assert len(rot.t) == 20_000 and rot.frames[0][0] is None
    img = rot.frames[0][1]
    assert img.shape == (180, 240) and 0.1 < img.mean() < 0.5  # the dark APS panel
    clips = read_anchor_clips(anchors / "data")
    assert clips[0].name == "ecd_slider_depth" and len(clips) == 5
    assert np.array_equal(clips[-1].t, rot.t)  # the rotation chunks in sorted order, shapes last
    with pytest.raises(FileNotFoundError, match="nowhere"):
        read_anchor_clips(anchors / "nowhere")


def test_planar_textures_and_renders_are_sane():
    assert not set(HELDOUT_PICTURES) & {n.split(":", 1)[1] for n in TRAIN_PICTURES}
    for name in TRAIN_PICTURES:
        pic = load_picture(name)
        assert pic.ndim == 2 and pic.min() >= 0 and pic.max() <= 1 and pic.std() > 0.05, name
    rng = np.random.default_rng(0)
    for kind in TEXTURE_KINDS:
        tex = random_texture(rng, 128, {kind: 1.0})
        assert tex.shape == (128, 128) and tex.dtype == np.float32
        assert tex.min() > 0 and tex.max() <= 1, kind
    scene = PlanarScene(np.random.default_rng(1), 64, 48, 0.5, dynamic_range=1000.0)
    a, b = scene.radiance(0.0), scene.radiance(0.25)
    assert a.shape == (48, 64) and (a > 0).all() and not np.allclose(a, b)
    again = PlanarScene(np.random.default_rng(1), 64, 48, 0.5, dynamic_range=1000.0)
    assert np.array_equal(again.radiance(0.25), b)


def test_a_texture_draw_ignores_the_order_of_the_weights():
    weights = {"picture": 0.3, "noise": 0.2, "flat": 0.2, "text": 0.1, "mosaic": 0.2}
    backwards = dict(reversed(weights.items()))
    for seed in range(6):
        a = random_texture(np.random.default_rng(seed), 128, weights)
        b = random_texture(np.random.default_rng(seed), 128, backwards)
        assert np.array_equal(a, b)


def test_mosaic_fills_occluding_disks_with_textures_of_their_own():
    for seed in range(4):
        # fills of 1/f noise (and the plain fill every mosaic may draw)
        tex = _mosaic_texture(
            np.random.default_rng(seed), 256, {"noise": 1.0, "mosaic": 1.0}, TRAIN_PICTURES
        )
        assert tex.shape == (256, 256) and tex.min() > 0 and tex.max() <= 1
        gy, gx = np.gradient(tex.astype(np.float64))
        assert (np.hypot(gx, gy) > 1e-3).mean() > 0.5  # texture inside the disks, not plain disks
        coarse = tex.reshape(16, 16, 16, 16).mean((1, 3))
        assert coarse.std() > 0.1  # disks of unrelated levels side by side, not one noise field
