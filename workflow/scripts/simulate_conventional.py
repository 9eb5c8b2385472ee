"""Snakemake adapter: simulate the conventional frame camera over one synthetic dataset."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.sim.simulate import simulate_conventional

setup_logging(snakemake.log[0])  # noqa: F821
simulate_conventional(
    snakemake.params.dataset,  # noqa: F821
    snakemake.params.simulator,  # noqa: F821
    Path(snakemake.output.conventional),  # noqa: F821
)
