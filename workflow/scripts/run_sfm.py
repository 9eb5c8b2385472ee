"""Snakemake adapter of rule run_sfm: a frames folder -> results/{dataset}/sfm/{source}/."""

from evdense.log import setup_logging
from evdense.sfm import SfmConfig, run_sfm

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
run_sfm(
    sm.params.frames,
    sm.output.model,
    SfmConfig.from_dict(sm.params.conf),
    num_threads=sm.threads,
)
