"""Snakemake adapter of rule refine_mesh: mesh.ply + dense workspace images -> refined.ply (+ scores)."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.mesh.stage import MeshConfig, refine_mesh, upstream_failed, write_empty_outputs

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
cloud = Path(sm.input.cloud)
if upstream_failed(sm.input.cloud):  # SfM recorded a failure: empty products
    write_empty_outputs(list(sm.output))
else:
    refine_mesh(
        sm.input.mesh,
        Path(sm.input.cloud).parent,
        sm.output.mesh,
        MeshConfig.from_dict(sm.params.conf),
        stats=sm.output.stats,
        threads=sm.threads,
    )
