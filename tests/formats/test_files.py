"""Atomic writes and the failed-stage record (evdense.formats.files, evdense.formats.status)."""

from __future__ import annotations

import json

import open3d as o3d
import pytest

from evdense.formats.files import atomic_path, read_json, write_atomic, write_json_atomic
from evdense.formats.status import (
    EMPTY_CLOUD_PLY,
    is_failed,
    write_empty_products,
    write_failed,
)


def test_an_interrupted_write_keeps_the_old_file(tmp_path):
    path = write_json_atomic(tmp_path / "a" / "stats.json", {"n": 1})
    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            tmp.write_text('{"n": ')  # half written
            raise RuntimeError("killed")
    assert read_json(path) == {"n": 1}
    assert sorted(p.name for p in path.parent.iterdir()) == ["stats.json"]
    out = write_atomic(tmp_path / "img.png", lambda t: t.write_bytes(t.suffix.encode()), True)
    assert out.read_bytes() == b".png"  # the temporary name kept the extension


def test_bad_json_is_named(tmp_path):
    (tmp_path / "x.json").write_text("{nope")
    with pytest.raises(ValueError, match=r"x\.json: not valid JSON"):
        read_json(tmp_path / "x.json")


def test_failure_record_and_empty_products(tmp_path):
    assert not is_failed(tmp_path)  # no stats.json: not failed
    write_json_atomic(tmp_path / "stats.json", {"failed": False})
    assert not is_failed(tmp_path)
    write_failed(tmp_path / "stats.json", "sfm failed")
    assert is_failed(tmp_path) and is_failed(tmp_path / "stats.json")
    outs = [tmp_path / n for n in ("mesh.ply", "mesh.obj", "texture.png", "eval.json", "m.glb")]
    write_empty_products(outs)
    mesh = o3d.io.read_triangle_mesh(str(outs[0]))
    assert len(mesh.vertices) == 0 and len(mesh.triangles) == 0
    assert json.loads(outs[3].read_text()) == {"failed": True, "reason": "sfm failed"}
    assert outs[4].stat().st_size == 0
    (tmp_path / "fused.ply").write_text(EMPTY_CLOUD_PLY)
    assert len(o3d.io.read_point_cloud(str(tmp_path / "fused.ply")).points) == 0
