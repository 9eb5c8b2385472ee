"""Snakemake adapter of rule run_sfm: a frames folder -> results/{dataset}/sfm/{source}/."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.sfm import SfmConfig, SfmError, run_sfm, write_failed_sfm

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
# on_failure and colmap_log_level are not params (changing them must not rerun finished models)
extra = {k: sm.config["sfm"][k] for k in ("on_failure", "colmap_log_level")}
conf = {**sm.params.conf, **extra}
if conf["calibration"] in ("auto", "dataset"):
    # a recording: the calibration ingest found in it (or the dataset's file, which ingest copies
    # there with precedence); `auto` estimates when there is none, `dataset` requires one
    found = Path(sm.input.gt) / "intrinsics.yaml" if sm.input.get("gt") else None
    if found is not None and found.is_file():
        conf["calibration"] = str(found)
    elif conf["calibration"] == "dataset":
        raise SystemExit(f"config key 'sfm.calibration' is 'dataset' but {sm.input.gt} holds no "
                         "intrinsics.yaml: the recording carries no calibration")  # fmt: skip
    else:
        conf["calibration"] = None
cfg = SfmConfig.from_dict(conf)
try:
    run_sfm(sm.params.frames, sm.output.model, cfg, num_threads=sm.threads)
except SfmError as e:
    if cfg.on_failure != "record":
        raise
    write_failed_sfm(sm.output.model, e)
