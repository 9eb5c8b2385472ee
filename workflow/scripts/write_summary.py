"""Adapter: rule write_summary -> evdense.evaluate.report.write_summary (+ the run's config)."""

from pathlib import Path

import pandas as pd
import yaml

from evdense.evaluate.report import write_summary
from evdense.log import setup_logging

setup_logging(snakemake.log[0])
write_summary(pd.read_csv(snakemake.input.csv), snakemake.output.md)
Path(snakemake.output.config).write_text(
    yaml.safe_dump(dict(snakemake.params.config), sort_keys=False)
)
