"""Snakemake adapter of rule texture_mesh: refined.ply + dense workspace images -> textured/."""

from pathlib import Path

from evdense.formats.status import is_failed, write_empty_products
from evdense.log import setup_logging
from evdense.texture.stage import run_texture

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
workspace = Path(sm.input.cloud).parent
if is_failed(workspace):  # SfM recorded a failure: empty products
    write_empty_products(list(sm.output))
else:
    run_texture(sm.input.mesh, workspace, Path(sm.output.obj).parent, sm.params.conf)
