"""Snakemake adapter: write the ground truth (mesh, poses, sharp frames, depth) of one synthetic dataset."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.sim.groundtruth import write_groundtruth

setup_logging(snakemake.log[0])  # noqa: F821
write_groundtruth(
    snakemake.params.dataset,  # noqa: F821
    snakemake.params.simulator,  # noqa: F821
    Path(snakemake.output.gt),  # noqa: F821
)
