"""Adapter: rule plot_figures -> evdense.evaluate.report.make_figures."""

import pandas as pd

from evdense.evaluate.report import make_figures
from evdense.log import setup_logging

setup_logging(snakemake.log[0])
make_figures(pd.read_csv(snakemake.input.csv), snakemake.output.figures)
