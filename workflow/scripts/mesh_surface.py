"""Snakemake adapter of rule mesh_surface: fused.ply + dense workspace -> mesh.ply."""

from pathlib import Path

from evdense.formats.status import is_failed, write_empty_products
from evdense.log import setup_logging
from evdense.mesh.stage import run_mesh

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
cloud = Path(sm.input.cloud)
if is_failed(cloud.parent):  # SfM recorded a failure: empty products
    write_empty_products(list(sm.output))
else:
    run_mesh(cloud, cloud.parent, sm.output.mesh, sm.wildcards.method, sm.params.conf)
