"""Snakemake adapter of rule refine_mesh: mesh.ply + dense workspace images -> refined.ply (+ scores)."""

from pathlib import Path

from evdense.formats.status import is_failed, write_empty_products
from evdense.log import setup_logging
from evdense.refine.stage import run_refine

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
workspace = Path(sm.input.cloud).parent
if is_failed(workspace):  # SfM recorded a failure: empty products
    write_empty_products(list(sm.output))
else:
    run_refine(
        sm.input.mesh,
        workspace,
        sm.output.mesh,
        sm.params.conf,
        stats=sm.output.stats,
        threads=sm.threads,
    )
