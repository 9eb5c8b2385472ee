"""Snakemake adapter of rule run_mvs: sparse model + frames -> results/{dataset}/mvs/{source}/."""

from pathlib import Path

from evdense.formats.files import write_text_atomic
from evdense.formats.status import EMPTY_CLOUD_PLY, SFM_FAILED, write_failed
from evdense.log import setup_logging
from evdense.mvs.stage import MVSConfig, run_mvs
from evdense.sfm import sfm_failed

# The guard keeps the CPU worker processes (multiprocessing "spawn") from re-running this script.
if __name__ == "__main__":
    sm = snakemake  # noqa: F821 (injected by Snakemake)
    log = setup_logging(sm.log[0])
    out = Path(sm.output.fused).parent
    if sfm_failed(sm.input.model):
        # SfM recorded a failure (sfm.on_failure: record): an empty cloud, marked failed.
        log.warning("%s: SfM failed, writing an empty dense cloud", sm.input.model)
        write_text_atomic(sm.output.fused, EMPTY_CLOUD_PLY)
        write_failed(sm.output.stats, SFM_FAILED)
    else:
        run_mvs(
            Path(sm.input.model) / "sparse" / "0",
            sm.params.frames,
            out,
            MVSConfig.from_dict(sm.params.conf),
            threads=sm.threads,
        )
