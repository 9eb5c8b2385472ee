"""Snakemake adapter of rule mesh_surface: fused.ply + dense workspace -> mesh.ply."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.mesh.stage import MeshConfig, mesh_surface, upstream_failed, write_empty_outputs

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
if upstream_failed(sm.input.cloud):  # SfM recorded a failure: empty products
    write_empty_outputs(list(sm.output))
else:
    cloud = Path(sm.input.cloud)
    mesh_surface(
        cloud,
        cloud.parent,
        sm.output.mesh,
        sm.wildcards.method,
        MeshConfig.from_dict(sm.params.conf),
    )
