"""A stage that could not run: the failed-stage record and the empty products that follow it.

With ``sfm.on_failure: record`` a run whose SfM fails does not stop a sweep: SfM writes a
``stats.json`` holding ``"failed": true`` (and why), and every later stage that finds such a record
upstream writes empty but valid products (a PLY with no vertices, an OBJ with no faces, ...) with
the same mark, so that the evaluation scores the run as empty and says why. This module is the one
place that writes and recognises that mark.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from evdense.formats.files import read_json, write_json_atomic, write_text_atomic

STATS_NAME = "stats.json"
"""The statistics file of a stage's output folder, where a failure is recorded."""

SFM_FAILED = "sfm failed"
"""The reason recorded by the stages after a failed SfM."""

EMPTY_CLOUD_PLY = (
    "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
    "property float z\nend_header\n"
)
"""A valid point cloud with no points."""

EMPTY_MESH_PLY = EMPTY_CLOUD_PLY.replace(
    "end_header\n", "element face 0\nproperty list uchar int vertex_indices\nend_header\n"
)
"""A valid triangle mesh with no triangles."""


def failed_record(reason: str, **extra: Any) -> dict[str, Any]:
    """The JSON record of a failed stage."""
    return {"failed": True, "reason": reason, **extra}


def is_failed(stats_path: str | Path) -> bool:
    """True when ``stats_path`` (a ``stats.json``, or a folder holding one) records a failure."""
    p = Path(stats_path)
    if p.is_dir():
        p = p / STATS_NAME
    return p.is_file() and bool(read_json(p).get("failed", False))


def write_failed(path: str | Path, reason: str = SFM_FAILED, **extra: Any) -> Path:
    """Write the failure record to ``path`` (a JSON file), atomically."""
    return write_json_atomic(path, failed_record(reason, **extra), indent=None)


def write_empty_products(paths: list[str | Path], reason: str = SFM_FAILED) -> None:
    """Write empty but valid files for the outputs of a stage that could not run: PLY (a mesh with
    no vertices and no faces), OBJ, PNG (1 x 1 black), JSON (the failure record); anything else
    empty. (An empty dense cloud is :data:`EMPTY_CLOUD_PLY`.)"""
    import imageio.v3 as iio

    for p in map(Path, paths):
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.suffix == ".ply":
            write_text_atomic(p, EMPTY_MESH_PLY)
        elif p.suffix == ".json":
            write_failed(p, reason)
        elif p.suffix == ".png":
            iio.imwrite(p, np.zeros((1, 1, 3), np.uint8))
        elif p.suffix == ".obj":
            write_text_atomic(p, f"# empty: {reason}\nmtllib mesh.mtl\n")
        else:
            p.write_bytes(b"")
