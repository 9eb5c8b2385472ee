"""Voxel grids: hand-computed values, fast paths == np.add.at reference, normalisation, the voxel file."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch

from evdense.events.container import EventFile, Events, write_events
from evdense.events.voxel import (
    HAVE_NUMBA,
    VoxelConfig,
    VoxelFile,
    find_hot_pixels,
    make_voxels,
    normalize_voxel,
    voxel_grid,
    voxel_grid_reference,
    voxel_grid_torch,
)
from evdense.events.windows import WindowConfig, make_windows

BACKENDS = ["numpy"] + (["numba"] if HAVE_NUMBA else [])


def _all_paths(t, x, y, p, bins, h, w, **kw):
    """The grid by every implementation: reference, numpy, numba, torch."""
    out = {"reference": voxel_grid_reference(t, x, y, p, bins, h, w)} if not kw else {}
    for b in BACKENDS:
        out[b] = voxel_grid(t, x, y, p, bins, h, w, backend=b, **kw)
    out["torch"] = voxel_grid_torch(t, x, y, p, bins, h, w, **kw).numpy()
    return out


def test_hand_made_events_give_hand_computed_grid():
    # window from t0 = 1000 us to t_last = 1100 us, B = 5: t* = 4 (t - 1000) / 100
    t = np.array([1000, 1025, 1050, 1060, 1060, 1090, 1100])
    x = np.array([0, 1, 2, 3, 3, 1, 2])
    y = np.array([0, 0, 1, 1, 1, 0, 1])
    p = np.array([1, -1, 1, 1, 1, -1, -1])
    # t*:        0,  1,  2, 2.4, 2.4, 3.6, 4
    exp = np.zeros((5, 2, 4), np.float32)
    exp[0, 0, 0] += 1.0  # first event of the window: all on bin 0
    exp[1, 0, 1] += -1.0  # t* exactly on bin 1
    exp[2, 1, 2] += 1.0  # t* exactly on bin 2
    exp[2, 1, 3] += 2 * 0.6  # two events at t* = 2.4 on one pixel: 0.6 to bin 2 ...
    exp[3, 1, 3] += 2 * 0.4  # ... and 0.4 to bin 3
    exp[3, 0, 1] += -0.4  # t* = 3.6: 0.4 to bin 3, 0.6 to bin 4
    exp[4, 0, 1] += -0.6
    exp[4, 1, 2] += -1.0  # last event of the window: all on the last bin
    for name, g in _all_paths(t, x, y, p, 5, 2, 4).items():
        np.testing.assert_allclose(g, exp, atol=1e-6, err_msg=name)
        assert g.dtype == np.float32 and g.shape == (5, 2, 4)


def test_equal_first_and_last_timestamp_puts_everything_in_bin_zero():
    t = np.full(4, 777)
    x, y, p = np.array([0, 1, 1, 2]), np.zeros(4, int), np.array([1, -1, -1, 1])
    exp = np.zeros((5, 1, 3), np.float32)
    exp[0, 0] = [1, -2, 1]
    for name, g in _all_paths(t, x, y, p, 5, 1, 3).items():
        np.testing.assert_allclose(g, exp, atol=1e-7, err_msg=name)


def test_one_bin_counts_polarities_and_empty_window_is_zero():
    t, x, y, p = np.array([0, 5, 10]), np.array([0, 0, 1]), np.zeros(3, int), np.array([1, 1, -1])
    for name, g in _all_paths(t, x, y, p, 1, 1, 2).items():
        np.testing.assert_allclose(g, [[[2, -1]]], atol=1e-7, err_msg=name)
    e = np.zeros(0, np.int64)
    for name, g in _all_paths(e, e, e, e, 5, 2, 2).items():
        assert not g.any(), name


def _random_events(rng, n, w=64, h=48, sort=True):
    t = rng.integers(0, 40_000, n)
    if sort:
        t = np.sort(t)
    return Events(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.choice([-1, 1], n))


@pytest.mark.parametrize("bins", [2, 5, 9])
def test_fast_paths_equal_reference_on_random_events(rng, bins):
    ev = _random_events(rng, 200_000)
    grids = _all_paths(ev.t, ev.x, ev.y, ev.p, bins, 48, 64)
    ref = grids.pop("reference")
    assert np.abs(ref).sum() > 0
    for name, g in grids.items():
        np.testing.assert_allclose(g, ref, atol=2e-5, err_msg=name)
    # the grid conserves polarity: each event spreads weight 1 over its two bins
    np.testing.assert_allclose(ref.sum(), ev.p.sum(), atol=1e-2)


def test_unsorted_events_and_pieces_give_the_same_grid(rng):
    ev = _random_events(rng, 50_000)
    ref = voxel_grid_reference(ev.t, ev.x, ev.y, ev.p, 5, 48, 64)
    t0, t1 = int(ev.t[0]), int(ev.t[-1])
    perm = rng.permutation(len(ev))
    sh = ev[perm]
    for b in BACKENDS:
        g = voxel_grid(sh.t, sh.x, sh.y, sh.p, 5, 48, 64, t0=t0, t1=t1, backend=b)
        np.testing.assert_allclose(g, ref, atol=2e-5, err_msg=f"unsorted {b}")
        out = np.zeros((5, 48, 64), np.float32)
        for a in range(0, len(ev), 7_001):  # one window built from pieces
            pc = ev[a : a + 7_001]
            voxel_grid(pc.t, pc.x, pc.y, pc.p, 5, 48, 64, t0=t0, t1=t1, out=out, backend=b)
        np.testing.assert_allclose(out, ref, atol=2e-5, err_msg=f"pieces {b}")
    gt = voxel_grid_torch(torch.from_numpy(sh.t), sh.x, sh.y, sh.p, 5, 48, 64, t0=t0, t1=t1)
    np.testing.assert_allclose(gt.numpy(), ref, atol=2e-5)


def test_events_off_the_sensor_are_refused():
    t, x, y, p = np.array([0, 1]), np.array([0, 4]), np.array([0, 0]), np.array([1, 1])
    for b in BACKENDS:
        with pytest.raises(ValueError, match="off the 4x2 sensor"):
            voxel_grid(t, x, y, p, 5, 2, 4, backend=b)
    with pytest.raises(ValueError, match="off the 4x2 sensor"):
        voxel_grid_torch(t, x, y, p, 5, 2, 4)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_torch_path_on_cuda_equals_reference(rng):
    ev = _random_events(rng, 100_000)
    ref = voxel_grid_reference(ev.t, ev.x, ev.y, ev.p, 5, 48, 64)
    g = voxel_grid_torch(ev.t, ev.x, ev.y, ev.p, 5, 48, 64, device="cuda")
    assert g.device.type == "cuda"
    np.testing.assert_allclose(g.cpu().numpy(), ref, atol=2e-5)


def test_normalize_voxel_makes_nonzero_entries_standard(rng):
    ev = _random_events(rng, 5_000, w=32, h=16)
    g = voxel_grid(ev.t, ev.x, ev.y, ev.p, 5, 16, 32) + 0.3 * (
        voxel_grid(ev.t, ev.x, ev.y, ev.p, 5, 16, 32) != 0
    )
    n = normalize_voxel(g)
    nz = g != 0
    np.testing.assert_array_equal(n != 0, nz)  # zeros stay zero
    assert abs(n[nz].mean()) < 1e-5
    assert abs(n[nz].std() - 1.0) < 1e-4
    np.testing.assert_allclose(n[nz], (g[nz] - g[nz].mean()) / g[nz].std(), atol=1e-4)
    nt = normalize_voxel(torch.from_numpy(g))
    assert isinstance(nt, torch.Tensor)
    np.testing.assert_allclose(nt.numpy(), n, atol=1e-5)
    batch = normalize_voxel(np.stack([g, 2 * g]))  # each grid on its own: scaling cancels
    np.testing.assert_allclose(batch[0], batch[1], atol=1e-5)
    assert not normalize_voxel(np.zeros((5, 2, 2))).any()
    one = normalize_voxel(np.pad(np.ones((1, 1, 1)), ((0, 4), (0, 1), (0, 1))))
    assert np.isfinite(one).all() and not one.any()  # a single value: centred, no division by 0


@pytest.fixture
def recording(tmp_path, rng):
    w, h, n = 24, 16, 30_000
    t = 500 + np.cumsum(rng.choice([0, 1, 2, 50], n))
    t[n // 2 :] += 100_000  # a 0.1 s silence: empty time windows
    ev = Events(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.choice([-1, 1], n))
    return write_events(tmp_path / "events.h5", ev, w, h), ev, w, h


@pytest.mark.parametrize(
    "win,block",
    [
        (WindowConfig(num_events=4000), 1 << 22),
        (WindowConfig(num_events=4000), 2500),
        (WindowConfig(mode="time", duration_ms=30, overlap=0.5), 1000),
    ],
    ids=["n4000", "n4000-small-reads", "dt30ms-ov0.5-small-reads"],
)
def test_make_voxels_stores_the_grid_of_every_window(recording, tmp_path, win, block):
    path, ev, w, h = recording
    wpath = make_windows(path, tmp_path / "windows.h5", win)
    out = make_voxels(
        path, wpath, tmp_path / "voxels.h5", VoxelConfig(bins=5, read_block_events=block)
    )
    assert not (tmp_path / "voxels.h5.partial").exists()
    with VoxelFile(out) as vf:
        assert (vf.bins, vf.height, vf.width) == (5, h, w)
        assert vf.normalized is False
        assert len(vf) == len(vf.t_end_us) == len(vf.i0)
        if win.mode == "time":
            assert np.any(vf.count == 0)  # empty windows are kept, as all-zero grids
        grids = np.stack(list(vf))
        assert grids.shape == (len(vf), 5, h, w) and grids.dtype == np.float32
        for k in range(len(vf)):
            e = ev[int(vf.i0[k]) : int(vf.i1[k])]
            ref = voxel_grid_reference(e.t, e.x, e.y, e.p, 5, h, w)
            np.testing.assert_allclose(grids[k], ref, atol=2e-5)
        np.testing.assert_array_equal(vf[len(vf) - 1], grids[-1])
    with h5py.File(out) as f:
        assert f["voxels"].chunks == (1, 5, h, w)
        assert f.attrs["spec"] == ("n4000" if win.mode == "events" else "dt30ms-ov0.5")


def test_make_voxels_float16_and_mismatched_windows(recording, tmp_path, rng):
    path, ev, w, h = recording
    wpath = make_windows(path, tmp_path / "windows.h5", WindowConfig(num_events=10_000))
    out = make_voxels(
        path, wpath, tmp_path / "v16.h5", VoxelConfig(bins=3, dtype="float16", compression="gzip")
    )
    with VoxelFile(out) as vf:
        e = ev[0:10_000]
        np.testing.assert_allclose(vf[0], voxel_grid(e.t, e.x, e.y, e.p, 3, h, w), atol=2e-2)
    small = write_events(tmp_path / "small.h5", ev[:100], w, h)
    with pytest.raises(ValueError, match="another event file"):
        make_voxels(small, wpath, tmp_path / "bad.h5", VoxelConfig())
    assert not (tmp_path / "bad.h5").exists()


def test_bad_voxel_config_is_refused():
    with pytest.raises(ValueError, match="dtype"):
        VoxelConfig(dtype="int8")
    with pytest.raises(ValueError, match="bins"):
        VoxelConfig(bins=0)


def test_real_recording_windows_and_voxels(anchors, tmp_path):
    """The DVXplorer anchor (111,954 real events, 320x240) through windows and voxels."""
    ingest = pytest.importorskip("evdense.io.ingest")
    events = tmp_path / "events.h5"
    ingest.ingest_recording(anchors / "data" / "dvxplorer_sample.aedat4", events)
    wpath = make_windows(events, tmp_path / "windows_n15000.h5", WindowConfig(num_events=15000))
    out = make_voxels(
        events, wpath, tmp_path / "voxels_n15000_b5.h5", VoxelConfig(hot_pixel_factor=0)
    )
    with VoxelFile(out) as vf, EventFile(events) as ef:
        assert (vf.width, vf.height, len(vf)) == (320, 240, 8)
        assert vf.hot_pixels.shape == (0, 2)
        assert vf.count.sum() == ef.num_events == 111_954
        for k in (0, len(vf) - 1):
            e = ef.read(int(vf.i0[k]), int(vf.i1[k]))
            g = vf[k]
            np.testing.assert_allclose(
                g, voxel_grid_reference(e.t, e.x, e.y, e.p, 5, 240, 320), atol=2e-5
            )
            # each event spreads its polarity over its two bins: the grid sums to the net polarity
            assert g.sum() == pytest.approx(float(e.p.sum()), abs=1e-2)
            # first and last events sit entirely in the first and last bins
            assert g[0, e.y[0], e.x[0]] != 0 and g[-1, e.y[-1], e.x[-1]] != 0

    # the hot-pixel filter (on by default) masks this sensor's few dozen hot pixels and nothing else
    filtered = make_voxels(events, wpath, tmp_path / "filtered.h5", VoxelConfig())
    with VoxelFile(out) as vf, VoxelFile(filtered) as hf, EventFile(events) as ef:
        hot = hf.hot_pixels
        assert 40 <= len(hot) <= 120  # 66 with the defaults
        a, b = vf.read(), hf.read()
        mask = np.zeros((240, 320), bool)
        mask[hot[:, 1], hot[:, 0]] = True
        assert not b[:, :, mask].any()
        np.testing.assert_array_equal(a[:, :, ~mask], b[:, :, ~mask])
        ev = ef.read(0, ef.num_events)
        counts = np.bincount(ev.y.astype(int) * 320 + ev.x, minlength=320 * 240)
        assert mask.ravel()[np.argsort(counts)[::-1][:20]].all()  # the 20 busiest pixels are hot


def test_hot_pixels_stand_alone_signal_does_not():
    rng = np.random.default_rng(0)
    counts = rng.poisson(8.0, (40, 50))  # texture seen by a moving camera
    counts[:, 20] = 400  # a one-pixel line that fires a lot (a flickering wire): signal
    counts[10:14, 30:34] = 300  # a small bright blob: signal
    hot = [(5, 5), (30, 40), (20, 8), (20, 9)]  # two alone, and an adjacent pair
    for y, x in hot:
        counts[y, x] = 250
    found = find_hot_pixels(counts, factor=10.0, min_ratio=3.0)
    assert sorted(found.tolist()) == sorted(y * 50 + x for y, x in hot)
    assert len(find_hot_pixels(counts, factor=0.0, min_ratio=3.0)) == 0
    # a quiet recording: a pixel with 3 events among pixels with 0 or 1 is not "hot"
    quiet = (rng.random((40, 50)) < 0.05).astype(int)
    quiet[7, 7] = 3
    assert len(find_hot_pixels(quiet, factor=2.0, min_ratio=3.0)) == 0
