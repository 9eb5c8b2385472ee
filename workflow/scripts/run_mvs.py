"""Snakemake adapter of rule run_mvs: sparse model + frames -> results/{dataset}/mvs/{source}/."""

import json
from pathlib import Path

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
        out.mkdir(parents=True, exist_ok=True)
        Path(sm.output.fused).write_text(
            "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
            "property float z\nend_header\n"
        )
        Path(sm.output.stats).write_text(json.dumps({"failed": True, "reason": "sfm failed"}))
    else:
        run_mvs(
            Path(sm.input.model) / "sparse" / "0",
            sm.params.frames,
            out,
            MVSConfig.from_dict(sm.params.conf),
            threads=sm.threads,
        )
