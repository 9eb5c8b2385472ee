"""The mesh stage (``python -m evdense.mesh``): the fused cloud of a dense workspace to a clean
surface mesh, by screened Poisson or by Delaunay tetrahedra labelled with a visibility graph cut.

Input is the MVS stage's dense workspace ``results/{dataset}/mvs/{source}/`` (``fused.ply`` and
its ``.vis``, ``sparse/``, ``images/``); the mesh goes to
``results/{dataset}/mesh/{source}/{method}/mesh.ply``, written under a temporary name and renamed
when complete. The next stages are :mod:`evdense.refine` and :mod:`evdense.texture`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evdense.config import section_from_dict
from evdense.formats.cloud import read_cloud
from evdense.log import get_logger
from evdense.mesh.cleanup import CleanupConfig, clean_mesh
from evdense.mesh.poisson import PoissonConfig, poisson_mesh
from evdense.mesh.views import read_views, write_mesh
from evdense.mesh.visibility import VisibilityConfig, estimate_visibility, visibility_mesh

log = get_logger("mesh")

METHODS = ("poisson", "visibility")
LATER_STAGE_SECTIONS = ("refine", "texture")
"""Sub-sections of the ``mesh`` config section that belong to :mod:`evdense.refine` and
:mod:`evdense.texture`."""


@dataclass
class MeshConfig:
    """The `mesh` section of the config: the mesher and its settings (its `refine` and `texture`
    sub-sections belong to :mod:`evdense.refine` and :mod:`evdense.texture`)."""

    method: str = "visibility"
    """Surface reconstruction method used for the default targets: poisson or visibility."""
    poisson: PoissonConfig = field(default_factory=PoissonConfig)
    """Screened Poisson settings."""
    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    """Delaunay + graph-cut settings."""
    cleanup: CleanupConfig = field(default_factory=CleanupConfig)
    """Clean-up after either mesher."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> MeshConfig:
        """Build from the config section; its ``refine`` and ``texture`` sub-sections (the later
        stages') are ignored, other unknown keys raise ``ValueError`` naming them."""
        d = {k: v for k, v in (d or {}).items() if k not in LATER_STAGE_SECTIONS}
        return section_from_dict(cls, d, "mesh")


def _conf(config: MeshConfig | dict | None) -> MeshConfig:
    return config if isinstance(config, MeshConfig) else MeshConfig.from_dict(config)


def run_mesh(
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
