"""Stage functions of the mesh rules: surface, refinement, texture (one public function each).

Inputs are the MVS stage's dense workspace ``results/{dataset}/mvs/{source}/`` (``fused.ply`` and
its ``.vis``, ``sparse/``, ``images/``); outputs go to ``results/{dataset}/mesh/{source}/{method}/``.
Every output is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evdense.config import section_from_dict
from evdense.formats.cloud import read_cloud
from evdense.formats.files import write_json_atomic
from evdense.formats.status import SFM_FAILED, STATS_NAME, is_failed, write_empty_products
from evdense.log import get_logger
from evdense.mesh.cleanup import CleanupConfig, clean_mesh
from evdense.mesh.poisson import PoissonConfig, poisson_mesh
from evdense.mesh.refine import RefineConfig, refine_vertices
from evdense.mesh.texture import TextureConfig, texture_mesh_views, write_textured_mesh
from evdense.mesh.views import make_mesh, read_mesh, read_views, write_mesh
from evdense.mesh.visibility import VisibilityConfig, estimate_visibility, visibility_mesh

log = get_logger("mesh")

METHODS = ("poisson", "visibility")


@dataclass
class MeshConfig:
    """The `mesh` section of the config: mesher choice and the settings of every mesh stage."""

    method: str = "visibility"
    """Surface reconstruction method used for the default targets: poisson or visibility."""
    poisson: PoissonConfig = field(default_factory=PoissonConfig)
    """Screened Poisson settings."""
    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    """Delaunay + graph-cut settings."""
    cleanup: CleanupConfig = field(default_factory=CleanupConfig)
    """Clean-up after either mesher."""
    refine: RefineConfig = field(default_factory=RefineConfig)
    """Photometric refinement settings."""
    texture: TextureConfig = field(default_factory=TextureConfig)
    """Texturing settings."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> MeshConfig:
        """Build from the config section (unknown keys raise ``ValueError`` naming them)."""
        return section_from_dict(cls, d, "mesh")


def _conf(config: MeshConfig | dict | None) -> MeshConfig:
    return config if isinstance(config, MeshConfig) else MeshConfig.from_dict(config)


def mesh_surface(
    cloud: str | Path,
    workspace: str | Path,
    output: str | Path,
    method: str = "visibility",
    config: MeshConfig | dict | None = None,
) -> Path:
    """Mesh the fused cloud of a dense workspace and clean the result.

    Args:
        cloud: ``fused.ply`` (points, normals, colours; ``fused.ply.vis`` is used when present).
        workspace: the dense workspace folder (its ``sparse/`` gives the cameras).
        output: the mesh PLY to write (metres, world frame, vertex colours when the cloud has them).
        method: ``poisson`` or ``visibility``.

    Without a ``.vis`` file the visibility mesher estimates which cameras see each point (see
    :func:`evdense.mesh.visibility.estimate_visibility`).
    """
    conf = _conf(config)
    if method not in METHODS:
        raise ValueError(f"unknown mesh method {method!r}; expected one of {METHODS}")
    t0 = time.monotonic()
    pc = read_cloud(cloud)
    views = read_views(workspace)
    log.info("%s: %d points, %d views", cloud, len(pc.points), len(views))
    if method == "poisson":
        mesh = poisson_mesh(pc.points, pc.normals, conf.poisson, pc.colors_float(), views.centers)
    else:
        vis = pc.visibility
        if vis is not None and max((int(v.max()) for v in vis if len(v)), default=-1) >= len(views):
            raise ValueError(f"{cloud}.vis: image indices beyond the {len(views)} registered views")
        if vis is None or sum(len(v) for v in vis) == 0:
            log.info("no visibility file: estimating visibility from the cameras")
            vis = estimate_visibility(pc.points, pc.normals, views, conf.visibility)
        mesh = visibility_mesh(pc.points, vis, views.centers, conf.visibility, pc.colors_float())
    mesh = clean_mesh(mesh, conf.cleanup)
    if len(mesh.triangles) == 0:
        raise ValueError(f"{cloud}: the mesh is empty after clean-up")
    write_mesh(output, mesh)
    log.info("wrote %s: %d faces (%.1f s)", output, len(mesh.triangles), time.monotonic() - t0)
    return Path(output)


def refine_mesh(
    mesh: str | Path,
    workspace: str | Path,
    output: str | Path,
    config: MeshConfig | dict | None = None,
    stats: str | Path | None = None,
    threads: int | None = None,
) -> Path:
    """Photometric refinement of ``mesh`` against the workspace images; writes ``output`` (PLY)
    and, when given, ``stats`` (JSON: photometric scores before, per level and after, seconds).

    The output never scores worse than the input (the input is kept when nothing improves).
    """
    conf = _conf(config)
    m = read_mesh(mesh)
    views = read_views(workspace)
    v, f = np.asarray(m.vertices), np.asarray(m.triangles)
    res = refine_vertices(v, f, views, conf.refine, threads=threads)
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


def texture_mesh(
    mesh: str | Path,
    workspace: str | Path,
    output_dir: str | Path,
    config: MeshConfig | dict | None = None,
) -> Path:
    """Texture ``mesh`` from the workspace images; writes ``output_dir/`` with ``mesh.obj``,
    ``mesh.mtl``, ``mesh_texture.png`` and ``mesh_colored.ply`` (written to a temporary folder,
    then renamed)."""
    conf = _conf(config)
    m = read_mesh(mesh)
    views = read_views(workspace)
    tm = texture_mesh_views(np.asarray(m.vertices), np.asarray(m.triangles), views, conf.texture)
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


# --- runs whose SfM failed (sfm.on_failure: record) ------------------------------------------
def upstream_failed(cloud: str | Path) -> bool:
    """True when the MVS output beside ``cloud`` records that its SfM failed."""
    return is_failed(Path(cloud).parent / STATS_NAME)


def write_empty_outputs(paths: list[str | Path]) -> None:
    """Empty but valid products for a run whose SfM failed, so a sweep goes on and the evaluation
    scores the run as empty (:func:`evdense.formats.status.write_empty_products`)."""
    write_empty_products(paths, SFM_FAILED)
