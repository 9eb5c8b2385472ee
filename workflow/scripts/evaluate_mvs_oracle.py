"""Snakemake adapter of rule evaluate_mvs_oracle: oracle MVS folder vs GT -> evaluation JSON."""

from pathlib import Path

from evdense.log import setup_logging
from evdense.mvs.oracle import evaluate_mvs, write_evaluation

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
result = evaluate_mvs(Path(sm.input.fused).parent, sm.input.gt, threshold=sm.params.threshold)
write_evaluation(sm.output.evaluation, result)
