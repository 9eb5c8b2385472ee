"""Adapter: rule gather_metrics -> evdense.evaluate.table.gather_metrics."""

from evdense.evaluate.table import gather_metrics
from evdense.log import setup_logging

setup_logging(snakemake.log[0])
gather_metrics(list(snakemake.input.metrics), snakemake.output.csv, snakemake.output.md)
