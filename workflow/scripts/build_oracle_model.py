"""Snakemake adapter of rule build_oracle_model: GT poses, intrinsics, depth -> oracle/sparse/0."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.mvs.oracle import OracleConfig, build_gt_model

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
conf = {k: v for k, v in sm.params.conf.items() if k != "threshold"}
build_gt_model(sm.input.gt, Path(sm.output.model) / "sparse" / "0", OracleConfig(**conf))
