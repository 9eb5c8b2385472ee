"""Snakemake adapter: simulate the event camera over one synthetic dataset."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.sim.simulate import simulate_events

setup_logging(snakemake.log[0])  # noqa: F821
simulate_events(
    snakemake.params.dataset,  # noqa: F821
    snakemake.params.simulator,  # noqa: F821
    Path(snakemake.output.events),  # noqa: F821
)
