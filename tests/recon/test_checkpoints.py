"""Checkpoints: the published weights load strictly and safely; our format round-trips;
pickles that try to run code are refused without running it."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import pytest
import torch

from evdense.recon.checkpoints import (
    CheckpointError,
    ForeignObject,
    infer_architecture,
    load_checkpoint,
    save_checkpoint,
)
from evdense.recon.inference import NetworkReconstructor
from evdense.recon.networks import E2VID, FireNet, FireNetPlus


def _moving_edge_voxels(n: int = 6, h: int = 40, w: int = 56, bins: int = 5) -> np.ndarray:
    """Voxel grids (n, bins, h, w) of a vertical edge moving right one pixel per bin."""
    v = np.zeros((n, bins, h, w), np.float32)
    for k in range(n):
        for b in range(bins):
            col = (k * bins + b) % (w - 2) + 1
            v[k, b, 5:-5, col] = 1.0
            v[k, b, 5:-5, col - 1] = -0.5
    return v


# ---------------------------------------------------------------------------------------------
# Published checkpoints (anchors)
# ---------------------------------------------------------------------------------------------


def test_published_firenet_loads_with_every_key(anchors):
    ck = load_checkpoint(anchors / "weights" / "firenet_1000.pth.tar")
    assert ck.arch == "firenet" and ck.source_format == "published"
    assert isinstance(ck.net, FireNet)
    assert ck.net.num_parameters() == 37_777
    assert ck.hparams["recurrent_resblocks"] == [0]
    raw = torch.load(
        anchors / "weights" / "firenet_1000.pth.tar", map_location="cpu", weights_only=True
    )
    assert ck.net.load_state_dict(raw["state_dict"], strict=True).missing_keys == []
    assert ck.info["epoch"] == 1000


def test_published_firenet_plus_loads_without_running_its_config_class(anchors):
    path = anchors / "weights" / "firenet_plus.pth"
    with pytest.raises(pickle.UnpicklingError, match="ConfigParser"):  # plain weights-only load
        torch.load(path, map_location="cpu", weights_only=True)
    ck = load_checkpoint(path)
    assert ck.arch == "firenet_plus" and isinstance(ck.net, FireNetPlus)
    assert ck.net.num_parameters() == 37_777
    # the foreign config object became inert data we can read
    cfg = ck.info["config"]
    assert cfg["_config"]["arch"]["args"]["base_num_channels"] == 16


@pytest.mark.parametrize("name", ["firenet_1000.pth.tar", "firenet_plus.pth"])
def test_published_networks_give_finite_frames_in_unit_range(anchors, name):
    ck = load_checkpoint(anchors / "weights" / name)
    rec = NetworkReconstructor(ck.net)
    frames = rec.run(_moving_edge_voxels())
    assert frames.shape == (6, 40, 56) and frames.dtype == np.float32
    assert np.isfinite(frames).all()
    assert frames.min() >= 0.0 and frames.max() <= 1.0


def _dvxplorer_voxels(path, per_window: int = 10_000, bins: int = 5):
    from evdense.events.voxel import voxel_grid
    from evdense.io import open_recording

    with open_recording(path) as rec:
        parts = list(rec.iter_events())
        h, w = rec.height, rec.width
    t = np.concatenate([p.t for p in parts])
    x = np.concatenate([p.x for p in parts]).astype(np.int64)
    y = np.concatenate([p.y for p in parts]).astype(np.int64)
    p = np.where(np.concatenate([q.p for q in parts]) > 0, 1, -1).astype(np.int8)
    grids = [
        voxel_grid(t[s : s + per_window], x[s : s + per_window], y[s : s + per_window],
                   p[s : s + per_window], bins, h, w)
        for s in range(0, len(t) - per_window + 1, per_window)
    ]  # fmt: skip
    return np.stack(grids)


@pytest.mark.parametrize("name", ["firenet_1000.pth.tar", "firenet_plus.pth"])
def test_published_networks_on_real_dvxplorer_events(anchors, name):
    voxels = _dvxplorer_voxels(anchors / "data" / "dvxplorer_sample.aedat4")
    assert voxels.shape == (11, 5, 240, 320)
    rec = NetworkReconstructor(load_checkpoint(anchors / "weights" / name).net)
    frames = rec.run(voxels)
    assert np.isfinite(frames).all()
    assert frames.min() >= 0.0 and frames.max() <= 1.0
    # a real scene, not a flat or saturated image: contrast builds up over the windows
    assert frames[-1].std() > 0.02
    assert 0.02 < float(np.mean(frames[-1])) < 0.98


# ---------------------------------------------------------------------------------------------
# Our format
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "net",
    [FireNet(), FireNetPlus(num_bins=3), E2VID(base_channels=8, num_encoders=2, norm="none")],
    ids=["firenet", "firenet_plus", "e2vid_small"],
)
def test_our_format_round_trips(tmp_path, net):
    torch.manual_seed(0)
    for p in net.parameters():
        torch.nn.init.normal_(p)
    path = save_checkpoint(net, tmp_path / "model.pt", provenance={"trained_on": "unit test"})
    meta = json.loads((tmp_path / "model.json").read_text())
    assert meta["arch"] == net.arch and meta["hparams"] == net.hparams()
    # a plain state_dict: the strictest torch loader reads it
    sd = torch.load(path, weights_only=True)
    assert set(sd) == set(net.state_dict())
    ck = load_checkpoint(path)
    assert ck.source_format == "evdense" and ck.info == {"trained_on": "unit test"}
    assert type(ck.net) is type(net) and ck.hparams == net.hparams()
    for k, v in net.state_dict().items():
        assert torch.equal(ck.net.state_dict()[k], v), k
    assert not list(tmp_path.glob("*.partial"))


def test_plain_state_dict_without_json_is_recognised(tmp_path):
    net = E2VID(base_channels=8, num_encoders=2)
    torch.save(net.state_dict(), tmp_path / "weights.pth")
    ck = load_checkpoint(tmp_path / "weights.pth")
    assert ck.arch == "e2vid" and ck.source_format == "state_dict"
    assert ck.hparams == net.hparams()


def test_dataparallel_prefix_and_old_batch_norm_buffers_are_accepted(tmp_path):
    net = E2VID(base_channels=8, num_encoders=2)
    sd = {f"module.{k}": v for k, v in net.state_dict().items() if "num_batches_tracked" not in k}
    torch.save(
        {"arch": "E2VIDRecurrent", "model": {"num_bins": 5}, "state_dict": sd}, tmp_path / "old.pth"
    )
    ck = load_checkpoint(tmp_path / "old.pth")
    assert ck.arch == "e2vid" and ck.hparams["norm"] == "BN"


def test_architecture_comes_from_the_keys_not_the_arch_field(tmp_path):
    # rpg_e2vid-style dict whose 'arch' says FireNet but whose weights are an E2VID
    net = E2VID(base_channels=8, num_encoders=3)
    torch.save({"arch": "FireNet", "model": {}, "state_dict": net.state_dict()}, tmp_path / "x.pth")
    ck = load_checkpoint(tmp_path / "x.pth")
    assert ck.arch == "e2vid" and ck.hparams["num_encoders"] == 3
    assert infer_architecture(FireNetPlus().state_dict())[0] == "firenet_plus"


def test_bad_checkpoints_raise_clear_errors(tmp_path):
    with pytest.raises(CheckpointError, match="no such checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a pickle at all")
    with pytest.raises(CheckpointError, match="junk.pt"):
        load_checkpoint(tmp_path / "junk.pt")
    torch.save({"conv.weight": torch.zeros(3)}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="no known network"):
        load_checkpoint(tmp_path / "other.pt")
    # JSON says FireNet+ but the weights are FireNet's
    save_checkpoint(FireNet(), tmp_path / "m.pt")
    meta = json.loads((tmp_path / "m.json").read_text())
    meta["arch"] = "firenet_plus"
    meta["hparams"] = {}
    (tmp_path / "m.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match="but the weights in m.pt are firenet"):
        load_checkpoint(tmp_path / "m.pt")
    # a JSON asking for a huge network is refused before anything is built from it
    meta["arch"], meta["hparams"] = "firenet", {"base_channels": 200000}
    (tmp_path / "m.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match="base_channels"):
        load_checkpoint(tmp_path / "m.pt")


def test_decompression_bomb_checkpoint_is_refused_unread(tmp_path):
    import zipfile

    from evdense.recon import checkpoints

    bomb = tmp_path / "bomb.pt"
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("archive/data/0", b"\0" * (checkpoints.MAX_CHECKPOINT_BYTES + 1))
    assert bomb.stat().st_size < 2 << 20
    with pytest.raises(CheckpointError, match="unpacks to"):
        load_checkpoint(bomb)


# ---------------------------------------------------------------------------------------------
# Malicious pickles
# ---------------------------------------------------------------------------------------------


class _Payload:
    """Unpickling this object calls os.system (a stand-in for arbitrary code)."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("zip_format", [True, False], ids=["zip", "legacy"])
def test_pickle_that_runs_code_is_refused_and_not_run(tmp_path, zip_format):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pth.tar"
    obj = {"arch": "FireNet", "state_dict": FireNet().state_dict(), "config": _Payload(marker)}
    torch.save(obj, path, _use_new_zipfile_serialization=zip_format)
    assert not marker.exists()
    with pytest.raises(CheckpointError, match="refused to load") as err:
        load_checkpoint(path)
    assert "system" in str(err.value)
    assert not marker.exists()  # the payload did not run


def test_pickle_beside_a_json_is_still_refused(tmp_path):
    marker = tmp_path / "pwned"
    save_checkpoint(FireNet(), tmp_path / "m.pt")
    torch.save({"w": _Payload(marker)}, tmp_path / "m.pt")
    with pytest.raises(CheckpointError, match="refused"):
        load_checkpoint(tmp_path / "m.pt")
    assert not marker.exists()


def test_foreign_object_is_inert():
    obj = ForeignObject.__new__(ForeignObject)
    obj.__setstate__({"_config": {"a": 1}})
    assert obj.state == {"_config": {"a": 1}}
    assert "keys=['_config']" in repr(obj)
