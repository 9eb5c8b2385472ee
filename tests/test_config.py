"""The config's defaults: they work on a fresh clone, and map-valued keys keep their defaults."""

from __future__ import annotations

import json
from pathlib import Path

from evdense.config import REPO_ROOT, validate_config


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
