"""Snakemake adapter of rule run_mvs: sparse model + frames -> results/{dataset}/mvs/{source}/."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.mvs.stage import MVSConfig, run_mvs

# The guard keeps the CPU worker processes (multiprocessing "spawn") from re-running this script.
if __name__ == "__main__":
    sm = snakemake  # noqa: F821 (injected by Snakemake)
    setup_logging(sm.log[0])
    run_mvs(
        Path(sm.input.model) / "sparse" / "0",
        sm.params.frames,
        Path(sm.output.fused).parent,
        MVSConfig.from_dict(sm.params.conf),
        threads=sm.threads,
    )
