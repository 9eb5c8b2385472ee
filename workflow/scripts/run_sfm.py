"""Snakemake adapter of rule run_sfm: a frames folder -> results/{dataset}/sfm/{source}/."""

from evdense.log import setup_logging
from evdense.sfm import SfmConfig, SfmError, run_sfm, write_failed_sfm

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
# on_failure and colmap_log_level are not params (changing them must not rerun finished models)
extra = {k: sm.config["sfm"][k] for k in ("on_failure", "colmap_log_level")}
cfg = SfmConfig.from_dict({**sm.params.conf, **extra})
try:
    run_sfm(sm.params.frames, sm.output.model, cfg, num_threads=sm.threads)
except SfmError as e:
    if cfg.on_failure != "record":
        raise
    write_failed_sfm(sm.output.model, e)
