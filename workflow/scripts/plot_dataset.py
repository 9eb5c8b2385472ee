"""Adapter: rule plot_dataset -> evdense.evaluate.dataset_figures.make_dataset_figures."""

from evdense.evaluate.dataset_figures import SourceFiles, make_dataset_figures
from evdense.log import setup_logging

setup_logging(snakemake.log[0])
make_dataset_figures(
    snakemake.wildcards.dataset,
    snakemake.output.figures,
    {k: SourceFiles.from_dict(v) for k, v in snakemake.params.sources.items()},
    gt_dir=snakemake.input.gt,
    events=snakemake.input.events,
    page=snakemake.output.page,
    eval_conf=snakemake.params.conf,
)
