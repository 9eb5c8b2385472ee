"""Training our reconstruction weights: simulated data, losses, the loop, resume, evaluation."""

from __future__ import annotations

import copy
import json
from dataclasses import asdict
from typing import Any

import h5py
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from skimage.metrics import structural_similarity

from evdense.events.voxel import voxel_grid
from evdense.recon.checkpoints import load_checkpoint, save_checkpoint
from evdense.recon.inference import NetworkReconstructor
from evdense.recon.networks import zero_states
from evdense.recon.postprocess import standardize_nonzero
from evdense.sim.render import RenderConfig, Renderer
from evdense.sim.scene import build_scene
from evdense.training.data import (
    TrainDataConfig,
    generate_dataset,
    load_split,
    power_targets,
    random_motion,
    random_room_spec,
    random_scene_spec,
    simulate_sequence,
)
from evdense.training.heldout import EvalConfig, evaluate_methods, frame_scores, read_heldout
from evdense.training.losses import (
    LossWeights,
    RandomFeatures,
    gradient_matching,
    lowfreq_l1,
    random_feature_loss,
    reconstruction_loss,
    ssim,
    temporal_consistency,
)
from evdense.training.train import (
    CropStreams,
    SequenceSampler,
    TrainConfig,
    _train_step,
    build_model,
    export_state_weights,
    latest_checkpoint,
    normalize_windows,
    playback_path,
    train_model,
    update_ema,
    validate,
)

TINY = {
    "num_train_sequences": 4,
    "num_val_sequences": 2,
    "num_heldout_sequences": 1,
    "batch_size": 4,
    "crop_size": 32,
    "sequence_length": 8,
    "tbptt_length": 4,
    "max_steps": 30,
    "warmup_steps": 2,
    "lr": 3e-3,
    "val_every": 30,
    "checkpoint_every": 15,
    "log_every": 10,
    "device": "cpu",  # bit-identical resume is a CPU property; CUDA has its own test
    "data": {
        "width": 64,
        "height": 48,
        "focal_px": 50.0,
        "windows_per_sequence": 10,
        "heldout_windows_per_sequence": 10,
        "texture_size": 128,
        "max_duration_s": 4.0,
    },
}


@pytest.fixture(scope="module")
def tiny_set(tmp_path_factory):
    """A tiny simulated set (4 train, 2 val, 1 held-out sequence of 10 windows at 64 x 48)."""
    conf = TrainConfig.from_dict(TINY)
    path = tmp_path_factory.mktemp("trainset") / "trainset_s0.h5"
    generate_dataset(path, conf.data, conf.splits(), seed=0)
    return conf, path


def test_sequence_is_seeded_and_well_formed():
    conf = TrainDataConfig(**TINY["data"])
    a = simulate_sequence(conf, "train", 7)
    b = simulate_sequence(conf, "train", 7)
    assert a is not None and b is not None
    n = a.recipe["events_per_window"]
    assert a.voxels.shape == (10, 5, 48, 64)
    assert np.array_equal(a.voxels, b.voxels) and np.array_equal(a.targets, b.targets)
    # every window holds exactly N events, and its voxel grid sums their polarities
    assert np.all(np.diff(a.window_index) == n)
    for k in (0, 9):
        s, e = a.window_index[k], a.window_index[k + 1]
        assert a.voxels[k].sum() == pytest.approx(float(a.events.p[s:e].sum()), abs=1e-2)
    assert np.all(np.diff(a.t_end_us) > 0)
    assert 0.0 <= a.targets.min() and a.targets.max() <= 1.0
    # the target is the log radiance mapped by the sequence's robust range
    lo, hi = a.log_range
    expect = np.clip((a.log_radiance - lo) / (hi - lo), 0, 1)
    assert np.allclose(a.targets, expect, atol=1e-5)
    c = a.recipe["event_camera"]["contrast_pos"]
    assert 0.1 / 1.5 <= c <= 1.2 * 1.5


@pytest.mark.parametrize("generator", ["planar", "scene3d"])
def test_both_generators_make_sequences(generator):
    conf = TrainDataConfig(**{**TINY["data"], "planar_fraction": float(generator == "planar")})
    seq = next(s for s in (simulate_sequence(conf, "train", i) for i in range(20)) if s is not None)
    assert seq.recipe["generator"] == generator
    assert seq.voxels.shape == (10, 5, 48, 64) and np.isfinite(seq.log_radiance).all()
    # the targets move: the camera (or the layers) moved between the first and the last window
    assert np.abs(seq.targets[-1] - seq.targets[0]).mean() > 0.01


def test_low_contrast_fraction_gives_plain_walls_in_training_scenes_only():
    def ratios(split, low_contrast):
        out = []
        for seed in range(20):
            spec = random_scene_spec(np.random.default_rng(seed), split, False, 64, low_contrast)
            out += [m["texture"]["high"] / m["texture"]["low"] for m in spec["materials"].values()]
        return np.array(out)

    assert ratios("train", 0.0).min() > 3.6  # the default recipe: every surface high-contrast
    plain = ratios("train", 1.0)
    assert plain.max() <= 3.0 + 1e-9 and plain.min() >= 1.05 - 1e-9
    assert np.array_equal(ratios("heldout", 0.0), ratios("heldout", 1.0))


def test_heldout_split_does_not_follow_the_training_recipe():
    base = TrainDataConfig(**TINY["data"])
    other = TrainDataConfig(**{**TINY["data"], "contrast_range": [0.5, 0.6], "planar_fraction": 1.0,
                               "noise_rate_range": [3.0, 4.0], "max_duration_s": 2.0,
                               "cutoff_hz": [50.0, 100.0], "room_fraction": 1.0})  # fmt: skip
    a = simulate_sequence(base, "heldout", 3)
    b = simulate_sequence(other, "heldout", 3)
    assert a is not None and b is not None
    assert a.recipe["generator"] == "scene3d"
    assert np.array_equal(a.voxels, b.voxels) and a.recipe == b.recipe


def test_limited_bandwidth_changes_the_events_and_nothing_else_of_a_seed():
    """``cutoff_hz`` draws each sequence's pixel bandwidth from a generator of its own: the scene,
    motion, thresholds and window size of a seed stay, its events change."""
    base = TrainDataConfig(**{**TINY["data"], "planar_fraction": 1.0})
    slow = TrainDataConfig(**{**asdict(base), "cutoff_hz": [20.0, 40.0]})
    a, b = simulate_sequence(base, "train", 0), simulate_sequence(slow, "train", 0)
    assert a is not None and b is not None
    assert a.recipe["event_camera"]["cutoff_hz"] == 0.0
    assert 20.0 <= b.recipe["event_camera"]["cutoff_hz"] <= 40.0
    cam_a, cam_b = dict(a.recipe["event_camera"]), dict(b.recipe["event_camera"])
    del cam_a["cutoff_hz"], cam_b["cutoff_hz"]
    assert cam_a == cam_b
    assert {k: v for k, v in a.recipe.items() if k not in ("event_camera", "duration_s")} == {
        k: v for k, v in b.recipe.items() if k not in ("event_camera", "duration_s")
    }
    assert not np.array_equal(a.voxels, b.voxels)
    for bad in ([0.0, 10.0], [30.0, 20.0], [-1.0, -1.0]):
        with pytest.raises(ValueError, match="cutoff_hz"):
            TrainDataConfig(**{**asdict(base), "cutoff_hz": bad}).check()


def test_rooms_enclose_the_camera_and_leave_the_other_sequences_of_a_seed_as_they_were():
    """``room_fraction`` turns a share of the sequences into rooms, drawn from a generator of its
    own: the sequences that are not rooms are bit-identical to those of the same seeds without."""
    base = TrainDataConfig(**{**TINY["data"], "planar_fraction": 0.5, "texture_size": 32})
    rooms = TrainDataConfig(**{**asdict(base), "room_fraction": 0.5})
    # at this fraction seed 0 draws a room and seed 4 a 3D scene (two cheap sequences of each kind)
    made = {seed: simulate_sequence(rooms, "train", seed) for seed in (0, 4)}
    kinds = {seed: bool(s.recipe.get("room")) for seed, s in made.items() if s is not None}
    assert kinds == {0: True, 4: False}
    for seed, is_room in kinds.items():
        if is_room:
            assert made[seed].recipe["generator"] == "scene3d"
            assert made[seed].recipe["scene"]["objects"][0]["type"] == "room"
        else:
            plain = simulate_sequence(base, "train", seed)
            assert plain is not None and np.array_equal(plain.voxels, made[seed].voxels)
    # the room encloses the camera wherever its motion takes it: every ray hits a wall at 0.4 m or
    # more (the surfaces stand 0.6 m or more away, the motion reaches a few tenths of a metre)
    render = RenderConfig(camera={"width": 48, "height": 36, "fx": 40.0, "fy": 40.0,
                                  "cx": 24.0, "cy": 18.0})  # fmt: skip
    for seed in range(3):
        rng = np.random.default_rng(seed)
        spec = random_room_spec(rng, hdr=seed == 0, size=32)
        scene = build_scene(spec, {"speed": 1.0, "dynamic_range": 10.0, "duration": 1.0,
                                   "seed": seed}, render, None)  # fmt: skip
        renderer, motion = Renderer(scene, supersample=1), random_motion(rng, "smooth")
        for t in np.linspace(0.0, 3.0, 5):
            out = renderer.render(motion.pose(float(t)))
            assert np.all(out.triangle_ids >= 0) and out.depth.min() > 0.4
    with pytest.raises(ValueError, match="room_fraction"):
        TrainDataConfig(**{**asdict(base), "room_fraction": 1.5}).check()


def test_target_power_derives_linear_targets_from_the_stored_log_radiance(tiny_set):
    _, path = tiny_set
    stored = load_split(path, "val")[1].astype(np.float32)
    assert np.allclose(load_split(path, "val", 0.0)[1], stored, atol=1e-3)
    lin = load_split(path, "val", 1.0)[1].astype(np.float32)
    with h5py.File(path, "r") as f:
        ranges = [f["val"][n]["log_radiance_range"][()] for n in sorted(f["val"])]
    for s, (lo, hi) in enumerate(ranges):
        # the stored log target t turned linear: (e^{(hi-lo)(t-1)} - f) / (1 - f)
        floor = np.exp(lo - hi)
        expect = (np.exp((hi - lo) * (stored[s] - 1)) - floor) / (1 - floor)
        assert np.allclose(lin[s], expect, atol=1e-2)
        # the same pixels clip at both ends, and the linear tone lies below the log one between
        assert np.all(lin[s][stored[s] == 0] == 0) and np.all(lin[s][stored[s] == 1] > 0.99)
        mid = (stored[s] > 0.05) & (stored[s] < 0.95)
        assert mid.any() and np.all(lin[s][mid] < stored[s][mid])
    # exact values: radiance e^0 .. e^2 over the range (0, 2), at the powers 0, 1 and 2
    logr = np.array([0.0, 1.0, 2.0], np.float32)
    assert np.allclose(power_targets(logr, (0.0, 2.0), 0.0), [0, 0.5, 1])
    e = np.e
    assert np.allclose(power_targets(logr, (0.0, 2.0), 1.0), [0, (e - 1) / (e**2 - 1), 1])
    assert np.allclose(power_targets(logr, (0.0, 2.0), 2.0), [0, (e**2 - 1) / (e**4 - 1), 1])
    with pytest.raises(ValueError, match="target_power"):
        TrainConfig.from_dict({"target_power": -0.5})


def test_ssim_matches_scikit_image():
    rng = np.random.default_rng(0)
    x = rng.random((40, 50))
    y = np.clip(x + 0.2 * rng.standard_normal((40, 50)), 0, 1)
    ours = float(ssim(torch.tensor(x)[None, None], torch.tensor(y)[None, None]))
    ref = structural_similarity(
        x, y, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
    )
    assert ours == pytest.approx(ref, abs=1e-6)
    t = torch.tensor(x)[None, None]
    assert float(ssim(t, t)) == pytest.approx(1.0)
    for data_range in (0.3, 0.1):  # the constants of a smaller range, as scikit-image sets them
        ours = float(
            ssim(torch.tensor(x)[None, None], torch.tensor(y)[None, None], data_range=data_range)
        )
        ref = structural_similarity(x, y, data_range=data_range, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False)  # fmt: skip
        assert ours == pytest.approx(ref, abs=1e-6)


def test_a_smaller_ssim_range_weighs_faint_texture():
    # a flat prediction of a faint texture (standard deviation 0.01): the standard SSIM hardly
    # sees the loss of the texture, the loss at range 0.3 does
    faint = 0.5 + 0.01 * torch.randn(4, 1, 32, 32, generator=torch.Generator().manual_seed(0))
    flat = torch.full_like(faint, 0.5)
    standard = LossWeights(l1=0.0, temporal=0.0)
    faint_aware = LossWeights(l1=0.0, temporal=0.0, ssim_range=0.3)
    loss = {w.ssim_range: float(reconstruction_loss(flat[None], faint[None], w)[0])
            for w in (standard, faint_aware)}  # fmt: skip
    assert loss[1.0] < 0.15 and loss[0.3] > 0.4
    assert float(reconstruction_loss(faint[None], faint[None], faint_aware)[0]) < 1e-6


def test_random_feature_loss_sees_structure_not_gain():
    # a textured target; a blurred copy and an offset copy with the same pixel L1: the perceptual
    # distance is zero for a gain about mid-grey and ranks the blur (lost structure) worst
    gen = torch.Generator().manual_seed(1)
    target = F.avg_pool2d(torch.rand(4, 1, 64, 64, generator=gen), 3, 1, padding=1)
    target = (target - target.amin()) / (target.amax() - target.amin())
    blurred = F.avg_pool2d(F.pad(target, (2, 2, 2, 2), mode="reflect"), 5, 1)
    err = (blurred - target).abs().mean()
    scaled = 0.5 + 1.7 * (target - 0.5)
    d = {name: float(random_feature_loss(p, target))
         for name, p in [("same", target), ("gain", scaled), ("offset", target + err),
                         ("blur", blurred), ("flat", torch.full_like(target, 0.5))]}  # fmt: skip
    assert d["same"] == pytest.approx(0.0, abs=1e-6) and d["gain"] < 1e-3
    assert 0.05 < d["offset"] < 0.7 * d["blur"] < d["flat"]
    # gradients reach the prediction only; the network is the same in every process
    pred = blurred.clone().requires_grad_(True)
    random_feature_loss(pred, target).backward()
    assert pred.grad is not None and float(pred.grad.abs().sum()) > 0
    a, b = RandomFeatures().state_dict(), RandomFeatures().state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not any(p.requires_grad for p in RandomFeatures().parameters())
    # the config weight reaches the loss
    _, terms = reconstruction_loss(blurred[None], target[None], LossWeights(perceptual=2.0))
    assert terms["perceptual"] == pytest.approx(d["blur"], rel=1e-5)
    assert reconstruction_loss(blurred[None], target[None], LossWeights())[1]["perceptual"] == 0


def test_temporal_consistency_sees_only_flicker():
    target = torch.rand(5, 2, 1, 8, 8)
    assert float(temporal_consistency(target + 0.3, target)) == pytest.approx(0.0, abs=1e-6)
    flicker = target + 0.1 * (torch.arange(5) % 2).view(5, 1, 1, 1, 1)
    assert float(temporal_consistency(flicker, target)) == pytest.approx(0.1, abs=1e-5)


def test_affine_invariant_loss_ignores_gain_and_offset_per_frame():
    target = torch.rand(4, 3, 1, 16, 16, dtype=torch.float64)
    gain = torch.tensor([0.5, 2.0, 1.3], dtype=torch.float64).view(1, 3, 1, 1, 1)
    pred = gain * target + torch.linspace(-0.2, 0.4, 4, dtype=torch.float64).view(4, 1, 1, 1, 1)
    inv = LossWeights(affine_invariant=True)
    loss, terms = reconstruction_loss(pred, target, inv)
    assert terms["l1"] < 1e-6 and terms["ssim"] == pytest.approx(1.0, abs=1e-6)
    assert float(loss) == pytest.approx(0.0, abs=1e-5)
    plain, _ = reconstruction_loss(pred, target, LossWeights())
    assert float(plain) > 0.1
    # the anchor term is the plain L1 of the raw output
    _, anchored = reconstruction_loss(pred, target, LossWeights(affine_invariant=True, anchor=0.1))
    assert anchored["loss"] == pytest.approx(0.1 * anchored["raw_l1"], abs=1e-5)
    assert anchored["raw_l1"] == pytest.approx(float((pred - target).abs().mean()))


def test_gradient_matching_sees_misplaced_edges_not_offsets():
    target = torch.zeros(1, 1, 32, 32, dtype=torch.float64)
    target[..., :, 16:] = 1.0  # a vertical edge
    assert float(gradient_matching(target + 0.4, target)) == pytest.approx(0.0, abs=1e-12)
    shifted = torch.zeros_like(target)
    shifted[..., :, 17:] = 1.0  # the edge one pixel to the right
    # full resolution: two columns of unit steps differ, 2 * 32 / (32 * 31) in x, none in y
    assert float(gradient_matching(shifted, target, scales=1)) == pytest.approx(2 / 31)
    blurred = torch.nn.functional.avg_pool2d(
        target, 5, stride=1, padding=2, count_include_pad=False
    )
    assert float(gradient_matching(blurred, target)) > 0.01
    # the loss term is off by default and adds its weight times the term when on
    pred = torch.stack([blurred, blurred])
    tgt = torch.stack([target, target])
    _, off = reconstruction_loss(pred, tgt, LossWeights())
    _, on = reconstruction_loss(pred, tgt, LossWeights(gradient=2.0))
    assert off["gradient"] == 0.0 and on["gradient"] > 0.01
    assert on["loss"] == pytest.approx(off["loss"] + 2.0 * on["gradient"], rel=1e-6)


def test_lowfreq_l1_sees_large_scale_levels_not_fine_texture():
    # a plain left half darker than the right half, both covered by a fine checkerboard
    yy, xx = torch.meshgrid(torch.arange(32), torch.arange(32), indexing="ij")
    checker = ((yy + xx) % 2).double()[None, None] * 0.2
    target = checker + torch.where(xx < 16, 0.2, 0.6).double()[None, None]
    # the texture lost, the levels kept: block means are unchanged, so no low-frequency error
    plain = torch.where(xx < 16, 0.3, 0.7).double()[None, None]
    assert float(lowfreq_l1(plain, target)) == pytest.approx(0.0, abs=1e-6)
    # the texture kept, the two halves merged to one level: 0.2 off everywhere at both block sizes
    merged = checker + 0.4
    assert float(lowfreq_l1(merged, target)) == pytest.approx(0.2)
    # a 4 px frame has no 8 x 8 block: only the 4 x 4 blocks count
    assert float(lowfreq_l1(merged[..., :4, :4], target[..., :4, :4])) == pytest.approx(0.2)
    pred, tgt = torch.stack([merged, merged]), torch.stack([target, target])
    _, off = reconstruction_loss(pred, tgt, LossWeights())
    _, on = reconstruction_loss(pred, tgt, LossWeights(lowfreq=3.0))
    assert off["lowfreq"] == 0.0 and on["lowfreq"] == pytest.approx(0.2)
    assert on["loss"] == pytest.approx(off["loss"] + 3.0 * 0.2, rel=1e-6)


def test_window_normalisation_matches_inference():
    rng = np.random.default_rng(1)
    vox = rng.standard_normal((3, 5, 12, 16)).astype(np.float32)
    vox[rng.random(vox.shape) < 0.7] = 0
    vox[0, 0, 0, :4] = [9.0, -7.0, 4.0, 2.5]  # cells above the pipeline's voxel clip of 3
    ours = normalize_windows(vox).float()
    clipped = normalize_windows(vox, clip=3.0).float()
    for k in range(3):
        ref = standardize_nonzero(torch.from_numpy(vox[k].copy())[None])[0]
        assert torch.allclose(ours[k], ref, atol=5e-3)  # float16 storage
    # with a clip, the training input is what the pipeline's reconstructor feeds its network
    net = build_model(TrainConfig.from_dict(TINY)).eval()
    for k in range(3):
        rec = NetworkReconstructor(net, channels_last=False, voxel_clip=3.0)
        with torch.no_grad():
            direct, _ = net(clipped[k : k + 1], None)
        assert np.allclose(rec(vox[k]), direct[0, 0].clamp(0, 1).numpy(), atol=2e-2)


def test_a_window_played_backward_is_its_bins_reversed_and_negated():
    rng = np.random.default_rng(3)
    n, h, w = 400, 12, 16
    t = np.sort(rng.uniform(1000.0, 9000.0, n))
    x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    p = rng.choice([-1, 1], n)
    fwd = voxel_grid(t, x, y, p, 5, h, w, t0=1000.0, t1=9000.0)
    # the same events in reversed time: t -> t0 + t1 - t, order reversed, polarity negated
    back = voxel_grid(
        (10000.0 - t)[::-1], x[::-1], y[::-1], -p[::-1], 5, h, w, t0=1000.0, t1=9000.0
    )
    assert np.allclose(back, -fwd[::-1], atol=1e-5)
    # and so after the input normalisation, as the sampler applies it
    nf, nb = normalize_windows(np.stack([fwd, back])).float()
    assert torch.allclose(nb, -nf.flip(0), atol=2e-3)


def test_playback_path_turns_at_both_ends_with_targets_at_the_window_ends():
    win, tgt, back = (a.tolist() for a in playback_path(4, 0, 13))
    assert win == [1, 2, 3, 3, 2, 1, 1, 2, 3, 3, 2, 1, 1]
    assert tgt == [1, 2, 3, 2, 1, 0, 1, 2, 3, 2, 1, 0, 1]
    assert back == [False, False, False, True, True, True] * 2 + [False]
    # a window played backward ends where the previous step's window started
    assert all(tgt[k] == (win[k] - 1 if back[k] else win[k]) for k in range(13))
    with pytest.raises(ValueError, match="at least 2 windows"):
        playback_path(1, 0, 3)


def test_reverse_playback_gives_sequences_longer_than_simulated():
    rng = np.random.default_rng(0)
    vox = rng.standard_normal((2, 5, 5, 8, 8)).astype(np.float32)
    tgt = rng.random((2, 5, 8, 8)).astype(np.float32)
    conf = {**TINY, "crop_size": 8, "sequence_length": 12, "tbptt_length": 4, "augment": False,
            "data": {**TINY["data"], "windows_per_sequence": 5}}  # fmt: skip
    with pytest.raises(ValueError, match="reverse_playback"):
        TrainConfig.from_dict(conf)
    sampler = SequenceSampler(vox, tgt, TrainConfig.from_dict({**conf, "reverse_playback": True}))
    x, y = sampler.batch(np.random.default_rng(1))
    assert x.shape == (12, 4, 5, 8, 8) and y.shape == (12, 4, 1, 8, 8)
    # every step is a stored window (forward) or its reversal (backward), with a stored target
    norm, stored = sampler.voxels.float(), sampler.targets.float()
    for k in range(12):
        v, t = x[k, 0], y[k, 0, 0]
        s = next(i for i in range(2) if any(torch.equal(t, stored[i, j]) for j in range(5)))
        assert any(
            torch.equal(v, norm[s, j]) or torch.equal(v, -norm[s, j].flip(0)) for j in range(5)
        )


def test_crop_streams_go_on_with_their_windows_and_start_staggered():
    rng = np.random.default_rng(0)
    vox = rng.standard_normal((3, 5, 5, 8, 8)).astype(np.float32)
    tgt = rng.random((3, 5, 8, 8)).astype(np.float32)
    conf = TrainConfig.from_dict({**TINY, "crop_size": 8, "batch_size": 2, "sequence_length": 4,
                                  "tbptt_length": 4, "stream_steps": 3,
                                  "data": {**TINY["data"], "windows_per_sequence": 5}})  # fmt: skip
    sampler = SequenceSampler(vox, tgt, conf)
    streams = CropStreams(sampler)
    gen = np.random.default_rng(1)
    steps, seqs, views, pos = [], [], [], []
    for _ in range(5):
        steps.append(streams.batch(gen))
        seqs.append(list(streams.seq))
        views.append(list(streams.views))
        pos.append(list(streams.pos))
    # stream 0 first lives 1 step, stream 1 two; then each lives 3
    fresh = [[bool(f) for f in step[2]] for step in steps]
    assert fresh == [[True, True], [True, False], [False, True], [False, False], [True, False]]
    # stream 0's life from step 1 to 3 is 12 consecutive windows of one playback path
    x = torch.cat([steps[k][0][:, 0] for k in (1, 2, 3)])
    y = torch.cat([steps[k][1][:, 0] for k in (1, 2, 3)])
    assert seqs[1][0] == seqs[3][0] and views[1][0] == views[3][0]
    win, tg, back = playback_path(5, (pos[1][0] - 4) % 8, 12)
    ex, ey = sampler.crop(seqs[1][0], win, tg, back, views[1][0])
    assert torch.equal(x, ex) and torch.equal(y, ey)
    assert back.any() and not back.all()  # it turned at an end of the sequence
    # a checkpoint's account of the streams continues them exactly
    again = CropStreams(sampler)
    again.load_state_dict(json.loads(json.dumps(streams.state_dict())))
    a, b = streams.batch(np.random.default_rng(2)), again.batch(np.random.default_rng(2))
    assert all(torch.equal(u, v) for u, v in zip(a, b, strict=True))
    with pytest.raises(ValueError, match="stream_steps"):
        TrainConfig.from_dict({**TINY, "stream_steps": 0}).check()
    # the rows of the streams that start anew lose their state, a GRU's or an LSTM's alike
    h, c = torch.ones(2, 3, 4, 4), torch.full((2, 3, 4, 4), 2.0)
    cut = zero_states([h, (h, c), None], torch.tensor([True, False]))
    assert cut is not None and cut[2] is None
    for t, v in ((cut[0], 1.0), (cut[1][0], 1.0), (cut[1][1], 2.0)):
        assert torch.equal(t[0], torch.zeros(3, 4, 4)) and torch.equal(
            t[1], torch.full((3, 4, 4), v)
        )
    assert zero_states([h], torch.tensor([True, True])) is None


@pytest.mark.slow
def test_short_training_lowers_validation_loss(tiny_set, tmp_path):
    conf, path = tiny_set
    v_vox, v_tgt = load_split(path, "val")
    v_vox, v_tgt = normalize_windows(v_vox), torch.from_numpy(v_tgt)
    before = validate(build_model(conf), v_vox, v_tgt, conf.loss_weights())
    res = train_model(conf, path, tmp_path / "run", tmp_path / "w.pt")
    assert res.step == conf.max_steps
    after = validate(load_checkpoint(tmp_path / "w.pt").net, v_vox, v_tgt, conf.loss_weights())
    assert after["loss"] < 0.8 * before["loss"]
    assert after["ssim"] > before["ssim"]
    meta = json.loads((tmp_path / "w.json").read_text())
    assert meta["arch"] == "firenet" and meta["provenance"]["seed"] == conf.seed
    assert meta["provenance"]["data_recipe"]["width"] == 64
    lines = (tmp_path / "run" / "history.jsonl").read_text().splitlines()
    assert any("val" in json.loads(ln) for ln in lines)


def _train_straight_and_split(path, tmp_path, **keys: Any) -> tuple[TrainConfig, dict, dict, dict]:
    """Train TINY with ``keys`` for 6 steps (checkpoints every 3) in one go
    (``tmp_path/straight``) and stopped after 3 steps and resumed (``tmp_path/split``): the
    config, the last checkpoints of both, and the split run's at its stop."""
    conf = TrainConfig.from_dict(
        {**TINY, "max_steps": 6, "checkpoint_every": 3, "val_every": 100, **keys}
    )
    straight, split = tmp_path / "straight", tmp_path / "split"
    train_model(conf, path, straight, straight / "w.pt")
    first = train_model(conf, path, split, split / "w.pt", max_steps=3)
    assert first.step == 3 and latest_checkpoint(split).name == "step_0000003.pt"
    mid = torch.load(latest_checkpoint(split), weights_only=True)
    assert train_model(conf, path, split, split / "w.pt").step == 6
    a = torch.load(latest_checkpoint(straight), weights_only=True)
    b = torch.load(latest_checkpoint(split), weights_only=True)
    assert a["step"] == b["step"] == 6
    return conf, a, b, mid


@pytest.mark.slow
def test_resume_gives_the_uninterrupted_state(tiny_set, tmp_path):
    _, a, b, _ = _train_straight_and_split(tiny_set[1], tmp_path)
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    sa, sb = a["optimizer"]["state"], b["optimizer"]["state"]
    assert all(torch.equal(sa[i]["exp_avg"], sb[i]["exp_avg"]) for i in sa)
    assert a["rng"] == b["rng"]


def test_burn_in_windows_run_before_the_crop_without_loss(tiny_set, tmp_path):
    conf = TrainConfig.from_dict({**TINY, "burn_in_windows": 6, "max_steps": 2})
    sampler = SequenceSampler(*load_split(tiny_set[1], "train"), conf)
    x, y = sampler.batch(np.random.default_rng(0))
    assert x.shape[0] == y.shape[0] == 14  # 6 + 8 windows: past the 10 simulated, played back
    net = build_model(conf)
    twin = copy.deepcopy(net)
    opt = torch.optim.Adam(twin.parameters(), lr=1e-3)
    with_burn, _ = _train_step(twin, opt, x, y, conf, conf.loss_weights())
    states = None  # the same loss windows from the state the burn-in leaves
    with torch.no_grad():
        for k in range(6):
            _, states = net(x[k], states)
    plain = TrainConfig.from_dict({**TINY, "max_steps": 2})
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    after, _ = _train_step(net, opt, x[6:], y[6:], plain, plain.loss_weights(), states)
    assert [round(t["loss"], 5) for t in with_burn] == [round(t["loss"], 5) for t in after]
    assert train_model(conf, tiny_set[1], tmp_path / "run", tmp_path / "w.pt").step == 2
    with pytest.raises(ValueError, match="burn_in_windows"):
        TrainConfig.from_dict({**TINY, "burn_in_windows": 4, "stream_steps": 2}).check()


@pytest.mark.slow
def test_streams_carry_the_state_between_steps_and_resume_exactly(tiny_set, tmp_path):
    path = tiny_set[1]
    conf, a, b, mid = _train_straight_and_split(path, tmp_path, stream_steps=4)
    # after 3 steps stream 3 (first life 4 steps) is still on its first crop: its state is
    # the network's after 24 windows, not zero
    assert json.loads(mid["streams"])["left"][3] == 1
    assert all(s[3].abs().sum() > 0 for s in mid["stream_states"])
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    assert a["streams"] == b["streams"] and a["rng"] == b["rng"]
    pairs = zip(a["stream_states"], b["stream_states"], strict=True)
    assert all(torch.equal(u, v) for u, v in pairs)
    plain = tmp_path / "plain"
    train_model(TrainConfig.from_dict({**TINY, "max_steps": 3}), path, plain, plain / "w.pt")
    with pytest.raises(ValueError, match="stream_steps"):  # a checkpoint made without streams
        train_model(conf, path, plain, plain / "w.pt")


def test_weight_average_moves_towards_the_trained_weights():
    a, b = (
        build_model(TrainConfig.from_dict(TINY)),
        build_model(TrainConfig.from_dict({**TINY, "seed": 1})),
    )
    avg = build_model(TrainConfig.from_dict(TINY))
    update_ema(avg, b, decay=0.75, step=10_000)
    for k, v in avg.state_dict().items():
        torch.testing.assert_close(v, 0.75 * a.state_dict()[k] + 0.25 * b.state_dict()[k])
    before = {k: v.clone() for k, v in avg.state_dict().items()}
    update_ema(avg, b, decay=0.999, step=0)  # early steps move by (1 + step) / (10 + step) at most
    for k, v in avg.state_dict().items():
        torch.testing.assert_close(v, 0.1 * before[k] + 0.9 * b.state_dict()[k])
    with pytest.raises(ValueError, match="ema_decay"):
        TrainConfig.from_dict({**TINY, "ema_decay": 1.0}).check()


@pytest.mark.slow
def test_weight_average_is_saved_and_resumes(tiny_set, tmp_path):
    path = tiny_set[1]
    conf, a, b, _ = _train_straight_and_split(path, tmp_path, val_every=6, ema_decay=0.9)
    straight = tmp_path / "straight"
    saved = load_checkpoint(straight / "w.pt").net.state_dict()
    for k in a["ema"]:
        assert torch.equal(a["ema"][k], b["ema"][k]), k
        assert torch.equal(saved[k], a["ema"][k]), k
    assert any(not torch.equal(a["ema"][k], a["model"][k]) for k in a["model"])
    for averaged, key in ((True, "ema"), (False, "model")):
        out = export_state_weights(latest_checkpoint(straight), tmp_path / f"{key}.pt", averaged)
        loaded = load_checkpoint(out)
        assert loaded.info["step"] == 6 and loaded.info["weights"] == key
        assert all(torch.equal(v, a[key][k]) for k, v in loaded.net.state_dict().items())
    plain = tmp_path / "plain"
    train_model(TrainConfig.from_dict({**TINY, "max_steps": 3}), path, plain, plain / "w.pt")
    with pytest.raises(ValueError, match="ema_decay"):
        train_model(conf, path, plain, plain / "w.pt")
    with pytest.raises(ValueError, match="step_0000003.pt"):
        export_state_weights(latest_checkpoint(plain), tmp_path / "none.pt", averaged=True)


def test_init_weights_starts_from_them_and_refuses_another_shape(tmp_path):
    donor = build_model(TrainConfig.from_dict({**TINY, "seed": 7}))
    save_checkpoint(donor, tmp_path / "donor.pt", {"note": "test"})
    conf = TrainConfig.from_dict({**TINY, "init_weights": str(tmp_path / "donor.pt")})
    tuned, fresh = build_model(conf), build_model(TrainConfig.from_dict(TINY))
    for k, v in donor.state_dict().items():
        assert torch.equal(tuned.state_dict()[k], v), k
    assert any(not torch.equal(fresh.state_dict()[k], v) for k, v in donor.state_dict().items())
    # a resumed run takes its weights from the checkpoint, not from init_weights
    resumed = build_model(conf, init=False).state_dict()
    assert all(torch.equal(resumed[k], v) for k, v in fresh.state_dict().items())
    wide = build_model(TrainConfig.from_dict({**TINY, "base_channels": 8}))
    save_checkpoint(wide, tmp_path / "narrow.pt")
    with pytest.raises(ValueError, match="narrow.pt"):
        build_model(TrainConfig.from_dict({**TINY, "init_weights": str(tmp_path / "narrow.pt")}))


def test_the_e2vid_class_network_trains_and_loads_as_what_it_is(tiny_set, tmp_path):
    conf, path = tiny_set
    conf = TrainConfig.from_dict(
        {**TINY, "arch": "e2vid", "base_channels": 4, "num_encoders": 2, "max_steps": 4,
         "val_every": 4, "checkpoint_every": 2, "stream_steps": 2}
    )  # fmt: skip
    train_model(conf, path, tmp_path / "run", tmp_path / "w.pt", max_steps=2)
    # its streams keep the state of each of its 2 recurrent encoders, at their resolutions
    mid = torch.load(latest_checkpoint(tmp_path / "run"), weights_only=True)
    assert [tuple(t.shape) for t in mid["stream_states"]] == [(4, 8, 16, 16), (4, 16, 8, 8)]
    assert train_model(conf, path, tmp_path / "run", tmp_path / "w.pt").step == 4
    loaded = load_checkpoint(tmp_path / "w.pt")
    assert loaded.arch == "e2vid"
    assert loaded.hparams["num_encoders"] == 2 and loaded.hparams["norm"] == "none"
    v_vox, _ = load_split(path, "val")  # 64 x 48: not a multiple of 2**num_encoders in general
    rec = NetworkReconstructor(loaded.net, device="cpu")
    img = rec(v_vox[0, 0].astype(np.float32)[:, :45, :61])
    assert img.shape == (45, 61) and np.isfinite(img).all()
    with pytest.raises(ValueError, match="train.arch"):
        build_model(TrainConfig.from_dict({**TINY, "arch": "unet"}))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_training_on_cuda_matches_cpu_and_resumes_on_cpu(tmp_path):
    # planar sequences only: this set needs no open3d, so the test runs on a bare CUDA machine
    base = {
        **TINY, "max_steps": 6, "checkpoint_every": 3, "val_every": 3, "num_heldout_sequences": 0,
        "data": {**TINY["data"], "planar_fraction": 1.0},
    }  # fmt: skip
    cpu = TrainConfig.from_dict(base)
    path = generate_dataset(tmp_path / "planar.h5", cpu.data, cpu.splits(), seed=0)
    gpu = TrainConfig.from_dict({**base, "device": "cuda"})
    train_model(cpu, path, tmp_path / "cpu", tmp_path / "cpu.pt", max_steps=3)
    train_model(gpu, path, tmp_path / "gpu", tmp_path / "gpu.pt", max_steps=3)
    meta = json.loads((tmp_path / "gpu.json").read_text())
    assert meta["provenance"]["device"].startswith("cuda")
    v_vox, v_tgt = load_split(path, "val")
    v_vox, v_tgt = normalize_windows(v_vox), torch.from_numpy(v_tgt)
    w = cpu.loss_weights()
    a = validate(load_checkpoint(tmp_path / "cpu.pt").net, v_vox, v_tgt, w)["loss"]
    b = validate(load_checkpoint(tmp_path / "gpu.pt").net, v_vox, v_tgt, w)["loss"]
    assert abs(a - b) < 0.05 * a  # same steps on the same crops: float rounding only
    resumed = train_model(cpu, path, tmp_path / "gpu", tmp_path / "gpu.pt")  # a CUDA run, on CPU
    assert resumed.step == 6


def test_evaluation_scores_a_perfect_method_as_perfect(tiny_set):
    _, path = tiny_set
    seq = read_heldout(path)[0]
    conf = EvalConfig()
    s = frame_scores(seq.targets[-1], seq.targets[-1], conf)
    assert s["ssim"] == pytest.approx(1.0) and s["mse"] == pytest.approx(0.0)
    rows = evaluate_methods(path, {"highpass": None, "integrate": None}, conf)
    assert [r["method"] for r in rows] == ["highpass", "integrate"]
    for r in rows:
        assert r["frames"] == 10 - conf.skip_windows
        assert -1.0 <= r["ssim"] < 1.0 and 0.0 < r["mse"] < 1.0


def test_config_rejects_unknown_keys():
    with pytest.raises(ValueError, match="bogus"):
        TrainConfig.from_dict({"bogus": 1})
    with pytest.raises(ValueError, match=r"train\.data: unknown keys \['nope'\]"):
        TrainConfig.from_dict({"data": {"nope": 1}})
    with pytest.raises(ValueError, match="tbptt"):
        TrainConfig.from_dict({"sequence_length": 10, "tbptt_length": 4})
    with pytest.raises(ValueError, match=r"planar_textures: unknown kinds \['leaves'\]"):
        TrainConfig.from_dict({"data": {"planar_textures": {"leaves": 1.0}}})
    with pytest.raises(ValueError, match="positive sum"):
        TrainConfig.from_dict({"data": {"planar_textures": {"flat": 0.0}}})


def test_mix_entries_inherit_the_main_recipe_and_keep_its_camera():
    conf = TrainConfig.from_dict({**TINY, "mix": [{"contrast_range": [0.12, 0.27]},
                                                  {"num_train_sequences": 2, "hdr_fraction": 0.0}]})  # fmt: skip
    a, b = conf.mix_recipes()
    assert (a.num_train_sequences, b.num_train_sequences) == (4, 2)
    assert (a.seed, b.seed) == (1000, 2000)  # other scenes and motions than the main set's
    assert a.recipe.contrast_range == [0.12, 0.27] and a.recipe.width == 64
    assert a.recipe.texture_size == 128 and b.recipe.hdr_fraction == 0.0
    assert b.recipe.contrast_range == conf.data.contrast_range
    assert TrainConfig.from_dict({**TINY, "mix": [{"seed": 0}]}).mix_recipes()[0].seed == 0
    for entry, error in [
        ({"width": 96}, r"train\.mix\[0\]: width must equal"),
        ({"windows_per_sequence": 12}, r"train\.mix\[0\]: windows_per_sequence must equal"),
        ({"bogus": 1}, r"train\.mix\[0\]: unknown keys \['bogus'\]"),
        ({"planar_textures": {"leaves": 1.0}}, r"train\.mix\[0\]\.planar_textures: unknown kinds"),
        ({"num_train_sequences": 0}, r"train\.mix\[0\]\.num_train_sequences must be an integer >= 1"),
        ({"num_train_sequences": 2.5}, r"train\.mix\[0\]\.num_train_sequences must be an integer"),
    ]:  # fmt: skip
        with pytest.raises(ValueError, match=error):
            TrainConfig.from_dict({**TINY, "mix": [entry]})


@pytest.mark.slow
def test_a_mixed_run_simulates_each_recipe_once_and_records_them(tmp_path, caplog):
    import logging

    from evdense.training.data import read_config
    from evdense.training.stage import run_training

    mix = {"num_train_sequences": 3, "planar_fraction": 1.0, "planar_textures": {"flat": 1.0}}
    base = {**TINY, "num_train_sequences": 2, "num_val_sequences": 1, "num_heldout_sequences": 0,
            "val_every": 2, "checkpoint_every": 2, "mix": [mix]}  # fmt: skip
    run = tmp_path / "run"
    with caplog.at_level(logging.INFO, logger="evdense"):
        run_training(TrainConfig.from_dict({**base, "max_steps": 2}), run, evaluate=False)
    assert any("training sequences: 2 + 3" in r.getMessage() for r in caplog.records)
    main, extra = run / "trainset_s0.h5", run / "trainset_s0_mix0.h5"
    assert read_config(extra).planar_textures == {"flat": 1.0}
    assert read_config(extra).width == 64 and read_config(main).planar_textures != {"flat": 1.0}
    assert len(load_split(extra, "train")[0]) == 3 and len(load_split(main, "train")[0]) == 2
    prov = json.loads((run / "evfirenet.json").read_text())["provenance"]
    assert prov["mix"] == [
        {"data_file": str(extra), "seed": 1000, "data_recipe": prov["mix"][0]["data_recipe"]}
    ]
    assert prov["mix"][0]["data_recipe"]["planar_textures"] == {"flat": 1.0}
    made = extra.stat().st_mtime_ns
    caplog.clear()
    edited = {**mix, "planar_textures": {"flat": 0.5, "noise": 0.5}}
    with caplog.at_level(logging.INFO, logger="evdense"):
        run_training(TrainConfig.from_dict({**base, "max_steps": 4, "mix": [edited]}), run,
                     evaluate=False)  # fmt: skip
    assert extra.stat().st_mtime_ns == made  # reused, not simulated again, and said so
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warned == [f"{extra}: reused, made with other planar_textures than the config "
                      "(delete it to simulate it again)"]  # fmt: skip
    assert json.loads((run / "history.jsonl").read_text().splitlines()[-1])["step"] == 4


def test_planar_texture_weights_reach_the_generator():
    def edges(kinds):
        data = {**TINY["data"], "planar_fraction": 1.0, "planar_textures": kinds}
        conf = TrainDataConfig(**data)
        seqs = [simulate_sequence(conf, "train", i) for i in range(3)]
        return np.mean([np.abs(np.diff(s.targets, axis=-1)).mean() for s in seqs if s is not None])

    assert edges({"flat": 1.0}) < 0.5 * edges({"grating": 1.0, "text": 1.0})


def test_picture_folders_join_the_planar_pictures(tmp_path):
    import imageio.v3 as iio

    from evdense.training.planar import find_pictures

    folder = tmp_path / "pictures"
    (folder / "sub").mkdir(parents=True)
    for i in range(200):  # plain pictures: with them the planar scenes lose many of their edges
        iio.imwrite(folder / "sub" / f"plain_{i:03d}.png", np.full((16, 16), 128, np.uint8))
    (folder / "notes.txt").write_text("not a picture")
    names = find_pictures((str(folder),))
    assert len(names) == 200 and names == tuple(sorted(names))
    assert all(n.startswith("file:") and n.endswith(".png") for n in names)

    def edges(dirs):
        data = {**TINY["data"], "planar_fraction": 1.0, "planar_textures": {"picture": 1.0},
                "picture_dirs": dirs}  # fmt: skip
        seqs = [simulate_sequence(TrainDataConfig(**data), "train", i) for i in range(3)]
        return np.mean([np.abs(np.diff(s.targets, axis=-1)).mean() for s in seqs if s is not None])

    # the same seeds: the two would be equal if the folder were ignored
    assert edges([str(folder)]) < 0.75 * edges([])
    with pytest.raises(ValueError, match=r"train\.data\.picture_dirs: .*missing is not a folder"):
        TrainConfig.from_dict({"data": {"picture_dirs": [str(tmp_path / "missing")]}})
    (tmp_path / "sub2").mkdir()
    with pytest.raises(ValueError, match=r"train\.mix\[0\]\.picture_dirs: .*sub2 holds no"):
        TrainConfig.from_dict({"mix": [{"picture_dirs": [str(tmp_path / "sub2")]}]}).mix_recipes()


def test_training_runs_as_a_module_with_the_train_command():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "evdense.training", "--help"],
                         capture_output=True, text=True, check=True).stdout  # fmt: skip
    assert "usage: evdense train" in out and "--workers" in out
