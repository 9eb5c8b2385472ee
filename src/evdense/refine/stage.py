"""The refinement stage (``python -m evdense.refine``): a surface mesh moved along its normals
until the workspace images agree on it (:mod:`evdense.refine.photometric`).

Input is a mesh of :mod:`evdense.mesh` and its dense workspace ``results/{dataset}/mvs/{source}/``
(``sparse/``, ``images/``); outputs are ``refined.ply`` and, when asked, ``refined.json`` (the
photometric scores). The settings are the config's ``mesh.refine`` section.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from evdense.config import section_from_dict
from evdense.formats.files import write_json_atomic
from evdense.mesh.views import make_mesh, read_mesh, read_views, write_mesh
from evdense.refine.photometric import RefineConfig, refine_vertices


def run_refine(
    mesh: str | Path,
    workspace: str | Path,
    output: str | Path,
    config: RefineConfig | dict[str, Any] | None = None,
    stats: str | Path | None = None,
    threads: int | None = None,
) -> Path:
    """Photometric refinement of ``mesh`` against the workspace images; writes ``output`` (PLY)
    and, when given, ``stats`` (JSON: photometric scores before, per level and after, seconds).

    ``config``: the ``mesh.refine`` section. The output never scores worse than the input (the
    input is kept when nothing improves).
    """
    conf = section_from_dict(RefineConfig, config, "mesh.refine")
    m = read_mesh(mesh)
    views = read_views(workspace)
    v, f = np.asarray(m.vertices), np.asarray(m.triangles)
    res = refine_vertices(v, f, views, conf, threads=threads)
    out = make_mesh(res.vertices, f)
    if m.has_vertex_colors():
        out.vertex_colors = m.vertex_colors
    out.compute_vertex_normals()
    write_mesh(output, out)
    if stats is not None:
        write_json_atomic(
            stats,
            {
                "score_input": res.score_input,
                "score_levels": res.score_levels,
                "score_output": res.score_output,
                "seconds": res.seconds,
                "score": "mean 1 - ZNCC over view pairs at full resolution (lower is better)",
            },
        )
    return Path(output)
