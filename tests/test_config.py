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


def test_the_schema_says_what_the_dataclasses_say():
    """Keys, defaults and descriptions of every dataclass-backed section: written once, in the
    dataclasses, copied into the schema by ``python -m evdense.config_schema --write``."""
    from evdense.config_schema import sync_schema

    assert sync_schema(load_schema()) == []


def test_a_stale_schema_is_found_and_rewritten():
    from evdense.config_schema import dump_schema, sync_schema

    schema = load_schema()
    window = schema["properties"]["events"]["properties"]["window"]["properties"]
    window["num_events"]["default"] = 1
    window["mode"]["description"] = "old words"
    assert sorted(sync_schema(schema)) == ["events.window.mode: description",
                                           "events.window.num_events: default"]  # fmt: skip
    assert window["num_events"]["default"] == 25000
    # what --write produces reads back to the same schema
    import yaml

    assert sync_schema(yaml.safe_load(dump_schema(schema))) == []
    # a key on one side only needs a person
    del window["overlap"]
    with pytest.raises(ValueError, match=r"events\.window: .*WindowConfig only \['overlap'\]"):
        sync_schema(schema)


def test_scenes_are_built_when_the_workflow_passes_the_builder(tmp_path):
    from evdense.config import ConfigError, check_config
    from evdense.sim.scene import load_scene

    conf = validate_config({"datasets": {"odd": {"scene": "no_such_scene.yaml"}}})
    check_config(conf, base_dir=tmp_path)  # config.py alone builds no scene
    with pytest.raises(ConfigError, match=r"datasets\.odd"):
        check_config(conf, base_dir=tmp_path, build_scene=load_scene)
