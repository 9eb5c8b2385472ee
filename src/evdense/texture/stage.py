"""The texture stage (``python -m evdense.texture``): a mesh textured from the workspace images
(:mod:`evdense.texture.texturing`) and written for the usual viewers.

Input is a (refined) mesh and its dense workspace ``results/{dataset}/mvs/{source}/``; the output
folder holds ``mesh.obj`` + ``mesh.mtl`` + ``mesh_texture.png``, ``mesh_colored.ply``,
``mesh.glb`` and ``texture.json``. The settings are the config's ``mesh.texture`` section.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from evdense.config import section_from_dict
from evdense.formats.files import write_json_atomic
from evdense.mesh.views import read_mesh, read_views
from evdense.texture.export import write_textured_mesh
from evdense.texture.model import TextureConfig
from evdense.texture.texturing import texture_mesh_views


def run_texture(
    mesh: str | Path,
    workspace: str | Path,
    output_dir: str | Path,
    config: TextureConfig | dict[str, Any] | None = None,
) -> Path:
    """Texture ``mesh`` from the workspace images; writes ``output_dir/`` with ``mesh.obj``,
    ``mesh.mtl``, ``mesh_texture.png``, ``mesh_colored.ply``, ``mesh.glb`` and ``texture.json``
    (written to a temporary folder, then renamed). ``config``: the ``mesh.texture`` section."""
    conf = section_from_dict(TextureConfig, config, "mesh.texture")
    m = read_mesh(mesh)
    views = read_views(workspace)
    tm = texture_mesh_views(np.asarray(m.vertices), np.asarray(m.triangles), views, conf)
    output_dir = Path(output_dir)
    tmp = output_dir.with_name(output_dir.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    write_textured_mesh(tmp, tm, "mesh")
    write_json_atomic(
        tmp / "texture.json",
        {
            "faces": len(tm.faces),
            "faces_unseen": int(np.sum(tm.face_view < 0)),
            "views_used": int(len(np.unique(tm.face_view[tm.face_view >= 0]))),
            "atlas_size": list(tm.atlas.shape[:2]),
        },
    )
    if output_dir.exists():
        shutil.rmtree(output_dir)
    os.replace(tmp, output_dir)
    return output_dir
