"""The config's defaults: they work on a fresh clone, and map-valued keys keep their defaults."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from evdense.config import REPO_ROOT, load_schema, validate_config


def _strings(x):
    if isinstance(x, dict):
        for v in x.values():
            yield from _strings(v)
    elif isinstance(x, list):
        for v in x:
            yield from _strings(v)
    elif isinstance(x, str):
        yield x


def test_no_default_points_outside_the_repository():
    conf = validate_config({"datasets": {"a": {"scene": "room"}}})
    outside = [s for s in _strings(conf) if s.startswith("..") or "shared/anchors" in s]
    assert outside == []
    # every default method's weights ship with the repository
    rec = conf["reconstruct"]
    for m in rec["methods"]:
        method = rec["presets"][m]["method"]
        if method in rec["checkpoints"]:
            assert (REPO_ROOT / rec["checkpoints"][method]).is_file(), method


def test_naming_one_checkpoint_keeps_the_shipped_ones():
    conf = validate_config({"datasets": {"a": {"scene": "room"}},
                            "reconstruct": {"checkpoints": {"firenet": "mine/firenet.pth"},
                                            "presets": {"hp2": {"method": "highpass"}}}})  # fmt: skip
    rec = conf["reconstruct"]
    assert rec["checkpoints"] == {"firenet": "mine/firenet.pth",
                                  "ours": "resources/weights/evfirenet.pt"}  # fmt: skip
    assert {"hp2", "ours", "firenet", "highpass"} <= set(rec["presets"])
    # a given entry is not overwritten by its default
    conf = validate_config({"datasets": {"a": {"scene": "room"}},
                            "reconstruct": {"checkpoints": {"ours": "other.pt"}}})  # fmt: skip
    assert conf["reconstruct"]["checkpoints"]["ours"] == "other.pt"


def test_default_config_file_validates_to_itself_twice():
    import yaml

    raw = yaml.safe_load((Path(REPO_ROOT) / "config" / "config.yaml").read_text())
    once = validate_config(raw)
    twice = validate_config(json.loads(json.dumps(once)))
    assert json.dumps(once) == json.dumps(twice)


# Every config section and the dataclass that reads it: the schema documents the keys, the
# dataclass holds them; this one test keeps the two in step (keys, defaults, descriptions).
SECTIONS = {
    "simulator.render": "evdense.sim.render:RenderConfig",
    "simulator.event_camera": "evdense.sim.esim:EventCameraConfig",
    "simulator.conventional_camera": "evdense.sim.conventional:ConventionalCameraConfig",
    "ingest": "evdense.io.ingest:IngestConfig",
    "events.window": "evdense.events.windows:WindowConfig",
    "events.voxel": "evdense.events.voxel:VoxelConfig",
    "events.summary": "evdense.events.summary:SummaryConfig",
    "reconstruct": "evdense.recon.config:ReconstructConfig",
    "mvs": "evdense.mvs.stage:MVSConfig",
    "mvs.oracle": "evdense.mvs.oracle:OracleConfig",
    "sfm": "evdense.sfm:SfmConfig",
    "evaluate": "evdense.evaluate.stage:EvalConfig",
    "mesh": "evdense.mesh.stage:MeshConfig",
    "train": "evdense.training.train:TrainConfig",
}


# Keys on one side only, on purpose: (schema only, dataclass only).
ONE_SIDED = {
    # the workflow's list of sources and the recipes they name; each source's ReconstructConfig
    # gets one method and one checkpoint from them
    "reconstruct": ({"methods", "presets", "checkpoints"}, {"method", "checkpoint"}),
    # the threshold of the oracle's evaluation, an argument of evaluate_mvs
    "mvs.oracle": ({"threshold"}, set()),
}


def _plain(v):
    """Defaults compared as JSON sees them (tuples are lists)."""
    return json.loads(json.dumps(v, default=list))


@pytest.mark.parametrize("path", sorted(SECTIONS))
def test_every_section_agrees_with_its_dataclass(path):
    import dataclasses
    import importlib

    module, name = SECTIONS[path].split(":")
    cls = getattr(importlib.import_module(module), name)
    props = load_schema()
    defaults = validate_config({})
    for part in path.split("."):
        props = props["properties"][part]
        defaults = defaults[part]

    def check(cls, props, defaults, where):
        fields = {f.name: f for f in dataclasses.fields(cls)}
        inst = cls()
        keys = set(props["properties"]) - {k for k in SECTIONS if k.startswith(f"{where}.")}
        keys = {k for k in keys if f"{where}.{k}" not in SECTIONS}
        schema_only, class_only = ONE_SIDED.get(where, (set(), set()))
        assert keys - schema_only == set(fields) - class_only, (
            f"{where}: schema only {keys - set(fields)}, dataclass only {set(fields) - keys}"
        )
        keys -= schema_only
        for k in keys:
            assert props["properties"][k].get("description"), f"{where}.{k}: no description"
            value = getattr(inst, k)
            if dataclasses.is_dataclass(value):
                check(type(value), props["properties"][k], defaults[k], f"{where}.{k}")
            else:
                assert _plain(defaults[k]) == _plain(value), (
                    f"{where}.{k}: schema {defaults[k]!r}, dataclass {value!r}"
                )

    check(cls, props, defaults, path)


def test_scenes_are_built_when_the_workflow_passes_the_builder(tmp_path):
    from evdense.config import ConfigError, check_config
    from evdense.sim.scene import load_scene

    conf = validate_config({"datasets": {"odd": {"scene": "no_such_scene.yaml"}}})
    check_config(conf, base_dir=tmp_path)  # config.py alone builds no scene
    with pytest.raises(ConfigError, match=r"datasets\.odd"):
        check_config(conf, base_dir=tmp_path, build_scene=load_scene)
