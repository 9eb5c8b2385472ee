"""The reconstruction stage: state carried across windows, resets at gaps, frames folders."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from evdense.events.container import Events, write_events
from evdense.events.voxel import VoxelConfig, VoxelFile, make_voxels
from evdense.events.windows import WindowConfig, make_windows
from evdense.formats.frames import FrameWriter, to_uint8
from evdense.recon.checkpoints import load_checkpoint, save_checkpoint
from evdense.recon.config import ReconstructConfig, resolve_config
from evdense.recon.inference import NetworkReconstructor
from evdense.recon.networks import E2VID, FireNet
from evdense.recon.postprocess import RobustRescaler, standardize_nonzero, unsharp_mask
from evdense.recon.stage import run_recon

H, W = 40, 48


def _bar_events(rng, t0_us: int, t1_us: int) -> Events:
    """A bright vertical bar sweeping right: + events at its leading edge, - at its trailing edge."""
    ts, xs, ys, ps = [], [], [], []
    for t in range(t0_us, t1_us, 1000):
        col = (t // 10_000) % (W - 4) + 3
        rows = rng.choice(np.arange(4, H - 4), 12, replace=False)
        for c, pol in ((col, 1), (col - 3, -1)):
            ts.append(np.full(len(rows), t))
            xs.append(np.full(len(rows), c))
            ys.append(rows)
            ps.append(np.full(len(rows), pol))
    return Events(*(np.concatenate(a) for a in (ts, xs, ys, ps)))


@pytest.fixture
def stream(tmp_path, rng):
    """events.h5 with a 1 s gap after 0.4 s (after window 4), windows of 2400 events, 5-bin voxels."""
    ev = Events.concatenate([_bar_events(rng, 0, 400_000), _bar_events(rng, 1_400_000, 1_800_000)])
    events = write_events(tmp_path / "events.h5", ev, W, H)
    windows = make_windows(events, tmp_path / "windows.h5", WindowConfig(num_events=2400))
    voxels = make_voxels(events, windows, tmp_path / "voxels.h5", VoxelConfig(bins=5))
    return events, voxels


def _random_firenet(seed: int = 0) -> FireNet:
    torch.manual_seed(seed)
    net = FireNet()
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.2)
    return net.eval()


def _read_folder(folder):
    rows = np.loadtxt(folder / "timestamps.txt", ndmin=2)
    frames = [np.asarray(Image.open(folder / f"{int(i):06d}.png")) for i in rows[:, 0]]
    return rows, frames


@pytest.mark.parametrize("arch", ["firenet", "e2vid"])
def test_one_pass_equals_window_by_window_with_state_handed_on(stream, arch):
    _, voxel_path = stream
    with VoxelFile(voxel_path) as vf:
        voxels = vf.read()
    torch.manual_seed(0)
    net = _random_firenet() if arch == "firenet" else E2VID(base_channels=8)
    for p in net.parameters():
        torch.nn.init.normal_(p, std=0.2)
    net.eval()
    one_pass = NetworkReconstructor(net).run(voxels)
    states, by_window = None, []
    for v in voxels:
        rec = NetworkReconstructor(net)  # a fresh reconstructor per window, state handed over
        rec.states = states
        by_window.append(rec(v))
        states = rec.states
    np.testing.assert_array_equal(one_pass, np.stack(by_window))
    # and the state matters: without it the frames differ
    fresh = np.stack([NetworkReconstructor(net)(v) for v in voxels])
    assert np.abs(fresh[1:] - one_pass[1:]).max() > 1e-3


def test_voxel_clip_keeps_an_hdr_burst_from_drowning_the_texture(stream):
    """A burst of 40 events per cell (an edge of 10^4 contrast passing) in one corner: uncapped, it
    sets the normalisation's spread and the frames elsewhere change; capped, they barely do."""
    _, voxel_path = stream
    with VoxelFile(voxel_path) as vf:
        voxels = vf.read()
    burst = voxels.copy()
    burst[:, 2, :6, :6] += 40.0
    net = load_checkpoint(Path(__file__).parents[2] / "resources/weights/evfirenet.pt").net
    plain = NetworkReconstructor(copy.deepcopy(net)).run(voxels)
    uncapped = NetworkReconstructor(copy.deepcopy(net)).run(burst)
    capped = NetworkReconstructor(copy.deepcopy(net), voxel_clip=2.0).run(burst)
    # the cap is applied before anything else: the same as clipping the input by hand
    by_hand = NetworkReconstructor(copy.deepcopy(net)).run(np.clip(burst, -2.0, 2.0))
    np.testing.assert_array_equal(capped, by_hand)
    far = (slice(None), slice(12, None), slice(12, None))  # away from the burst's corner
    change_uncapped = np.abs(uncapped[far] - plain[far]).mean()
    change_capped = np.abs(capped[far] - plain[far]).mean()
    assert change_uncapped > 2.5 * change_capped
    with pytest.raises(ValueError, match="voxel_clip"):
        NetworkReconstructor(net, voxel_clip=-1.0)


@pytest.mark.parametrize("arch", ["firenet", "e2vid"])
def test_bfloat16_frames_stay_close_to_float32(stream, arch):
    _, voxel_path = stream
    with VoxelFile(voxel_path) as vf:
        voxels = vf.read()
    torch.manual_seed(1)
    if arch == "firenet":  # our shipped weights
        net = load_checkpoint(Path(__file__).parents[2] / "resources/weights/evfirenet.pt").net
    else:
        net = E2VID(base_channels=8).eval()
    ref = NetworkReconstructor(copy.deepcopy(net)).run(voxels)
    half = NetworkReconstructor(copy.deepcopy(net), precision="bfloat16")
    assert next(half.net.parameters()).dtype == torch.bfloat16
    out = half.run(voxels)
    assert out.dtype == np.float32 and np.isfinite(out).all()
    # bf16 keeps 8 bits of mantissa: a few grey levels, not drift, over the whole stream
    assert np.abs(out - ref).max() < 0.02 and np.abs(out - ref).mean() < 0.004
    with pytest.raises(ValueError, match="precision"):
        NetworkReconstructor(net, precision="float16")


def test_stage_writes_frames_and_resets_at_gaps(stream, tmp_path):
    _, voxel_path = stream
    net = _random_firenet()
    ck = save_checkpoint(net, tmp_path / "net.pt")
    out = tmp_path / "frames" / "mine_n2400_b5"
    conf = ReconstructConfig(method="mine", checkpoint=str(ck), max_gap_s=0.5)
    assert run_recon(voxel_path, out, conf, num_threads=1) == out

    with VoxelFile(voxel_path) as vf:
        voxels, t_end, t_start = vf.read(), vf.t_end_us, vf.t_start_us
    rows, frames = _read_folder(out)
    assert len(frames) == len(voxels) == len(list(out.glob("*.png")))
    np.testing.assert_array_equal(rows[:, 0], np.arange(len(voxels)))
    np.testing.assert_allclose(rows[:, 1], t_end * 1e-6, atol=1e-6)
    assert frames[0].dtype == np.uint8 and frames[0].shape == (H, W)
    assert not [p for p in out.parent.iterdir() if p.name != out.name]  # no temporary folders

    # expected: the state is carried, except across the 1 s gap where it starts again
    gap = int(np.argmax(t_start[1:] - t_end[:-1] > 500_000)) + 1
    assert gap == 4
    rec = NetworkReconstructor(net, voxel_clip=conf.voxel_clip)  # the stage caps voxels at 3
    for k, v in enumerate(voxels):
        if k == gap:
            rec.reset()
        np.testing.assert_array_equal(frames[k], to_uint8(rec(v)), err_msg=f"frame {k}")
    # without the reset the frame after the gap would differ
    carried = NetworkReconstructor(net, voxel_clip=conf.voxel_clip).run(voxels)
    assert np.abs(to_uint8(carried[gap]).astype(int) - frames[gap]).max() > 0

    # the same stage from the command line, the preset named in a config file
    from evdense.recon.__main__ import main

    cfg = tmp_path / "recon.yaml"
    cfg.write_text(f"reconstruct:\n  max_gap_s: 0.5\n  checkpoints:\n    mine: {ck}\n")
    cli_out = tmp_path / "cli_frames"
    main(
        [str(voxel_path), str(cli_out), "--preset", "mine", "--config", str(cfg), "--threads", "1"]
    )
    cli_rows, cli_frames = _read_folder(cli_out)
    np.testing.assert_array_equal(cli_rows, rows)
    for a, b in zip(cli_frames, frames, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("method", ["highpass", "integrate"])
def test_baselines_reconstruct_from_events(stream, tmp_path, method):
    events, voxel_path = stream
    out = tmp_path / method
    conf = ReconstructConfig(method=method, cutoff_rad_s=5.0, leak_rad_s=0.0)
    run_recon(voxel_path, out, conf, events_path=events)
    rows, frames = _read_folder(out)
    with VoxelFile(voxel_path) as vf:
        assert len(frames) == vf.num_windows
        np.testing.assert_allclose(rows[:, 1], vf.t_end_us * 1e-6, atol=1e-6)
    # the bar leaves a bright/dark trail: every frame uses the range after the rescale
    assert all(f.max() - f.min() > 100 for f in frames)


def test_complementary_filter_with_conventional_frames(stream, tmp_path):
    events, voxel_path = stream
    ref = tmp_path / "conventional"
    ref.mkdir()
    grad = np.tile(np.linspace(20, 235, W, dtype=np.uint8), (H, 1))
    for i in range(2):
        Image.fromarray(grad).save(ref / f"{i:06d}.png")
    (ref / "timestamps.txt").write_text("0 0.0\n1 1.0\n")
    conf = ReconstructConfig(method="highpass", cutoff_rad_s=50.0, use_conventional_frames=True)
    out = tmp_path / "hp"
    run_recon(voxel_path, out, conf, events_path=events, reference_frames_dir=ref)
    _, frames = _read_folder(out)
    # a fast filter forgets the events and follows the reference: left dark, right bright
    last = frames[-1].astype(float)
    assert last[:, : W // 4].mean() + 60 < last[:, -W // 4 :].mean()


def test_bad_inputs_leave_no_output(stream, tmp_path):
    events, voxel_path = stream
    net = FireNet(num_bins=3)
    ck = save_checkpoint(net, tmp_path / "b3.pt")
    out = tmp_path / "frames" / "x"
    with pytest.raises(ValueError, match="5 bins"):
        run_recon(voxel_path, out, ReconstructConfig(method="x", checkpoint=str(ck)))
    with pytest.raises(ValueError, match="events_path"):
        run_recon(voxel_path, out, ReconstructConfig(method="highpass"))
    assert not out.exists()
    assert not (tmp_path / "frames").exists() or not list((tmp_path / "frames").iterdir())


def test_presets_resolve_against_the_shared_options():
    section = {
        "auto_hdr": True,
        "cutoff_rad_s": 5.0,
        "presets": {
            "hp2": {"method": "highpass", "cutoff_rad_s": 2.0},
            "fp": {"method": "firenet_plus"},
        },
        "checkpoints": {"firenet_plus": "w/fp.pth", "firenet": "w/f.pth"},
        "methods": ["hp2"],
    }
    hp2 = resolve_config(section, "hp2")
    assert (hp2.method, hp2.cutoff_rad_s, hp2.auto_hdr) == ("highpass", 2.0, True)
    assert resolve_config(section, "fp").checkpoint == "w/fp.pth"
    assert resolve_config(section, "firenet").checkpoint == "w/f.pth"  # bare method name
    assert resolve_config(section, "integrate").method == "integrate"
    with pytest.raises(ValueError, match="unknown reconstruct preset"):
        resolve_config(section, "nope")
    with pytest.raises(ValueError, match="needs a checkpoint"):
        resolve_config({**section, "presets": {"e": {"method": "e2vid"}}}, "e")
    with pytest.raises(ValueError, match=r"reconstruct: unknown keys \[.colour.\]"):
        ReconstructConfig.from_dict({"method": "firenet", "colour": True})


def test_standardize_nonzero_matches_the_published_definition(rng):
    v = np.zeros((5, 30, 40), np.float32)
    idx = rng.random(v.shape) < 0.1
    v[idx] = rng.normal(0.3, 2.0, idx.sum())
    x = torch.from_numpy(v.copy())
    nz = x[x != 0]
    expected = torch.where(x != 0, (x - nz.mean()) / nz.std(), torch.zeros(()))  # rpg_e2vid
    torch.testing.assert_close(standardize_nonzero(x.clone()), expected, rtol=1e-5, atol=1e-5)
    zeros = torch.zeros(5, 4, 4)
    assert torch.equal(standardize_nonzero(zeros.clone()), zeros)
    same = torch.zeros(5, 4, 4)
    same[0, 1, 1] = same[2, 3, 0] = 0.7
    out = standardize_nonzero(same.clone())
    assert torch.isfinite(out).all() and float(out.abs().max()) < 1e-6


def test_robust_rescaler_median_filters_the_bounds():
    r = RobustRescaler(min_percentile=0, max_percentile=100, window=3, border=0)
    ramp = np.linspace(0, 1, 100, dtype=np.float32).reshape(10, 10)
    np.testing.assert_allclose(r(ramp), ramp, atol=1e-6)
    # bounds so far [0, 1], [0, 2]: the median upper bound is 1.5
    np.testing.assert_allclose(r(ramp * 2), np.clip(ramp * 2 / 1.5, 0, 1), atol=1e-6)
    # third frame [0, 4]: median of (1, 2, 4) is 2
    np.testing.assert_allclose(r(ramp * 4), np.clip(ramp * 2, 0, 1), atol=1e-6)
    img = np.full((9, 9), 0.5, np.float32)
    img[4, 4] = 1.0
    assert unsharp_mask(img, 1.0, 1.0)[4, 4] == 1.0  # clipped
    assert unsharp_mask(img, 1.0, 1.0)[4, 3] < 0.5  # the halo darkens


def test_frame_writer_is_atomic(tmp_path):
    out = tmp_path / "frames"
    with pytest.raises(RuntimeError):
        with FrameWriter(out) as w:
            w.write(np.zeros((4, 5), np.float32), 0.5)
            raise RuntimeError("stage failed")
    assert not out.exists() and not list(tmp_path.iterdir())
    with FrameWriter(out) as w:
        w.write(np.full((4, 5), 0.5, np.float32), 0.25)
        w.write(np.ones((4, 5), np.uint8) * 7, 1.5)
    assert (out / "timestamps.txt").read_text() == "0 0.250000\n1 1.500000\n"
    assert np.asarray(Image.open(out / "000000.png"))[0, 0] == 128
    assert np.asarray(Image.open(out / "000001.png"))[0, 0] == 7


def test_bfloat16_on_a_cpu_without_it_is_flagged(caplog):
    """The stage warns when bfloat16 would be emulated (AVX2-only CPUs), and only then."""
    from evdense.recon.inference import cpu_has_fast_bf16
    from evdense.recon.networks import build_network

    torch.manual_seed(0)
    with caplog.at_level("WARNING", logger="evdense"):
        NetworkReconstructor(build_network("firenet"), precision="bfloat16")
    warned = any("emulated" in r.getMessage() for r in caplog.records)
    assert warned == (not cpu_has_fast_bf16())
