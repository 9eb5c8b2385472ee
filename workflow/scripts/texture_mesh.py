"""Snakemake adapter of rule texture_mesh: refined.ply + dense workspace images -> textured/."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.mesh.stage import MeshConfig, texture_mesh, upstream_failed, write_empty_outputs

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
cloud = Path(sm.input.cloud)
if upstream_failed(sm.input.cloud):  # SfM recorded a failure: empty products
    write_empty_outputs(list(sm.output))
else:
    texture_mesh(
        sm.input.mesh,
        Path(sm.input.cloud).parent,
        Path(sm.output.obj).parent,
        MeshConfig.from_dict(sm.params.conf),
    )
