"""Snakemake adapter of rule train_model: simulate the training set, train, keep the best weights."""

from evdense.log import setup_logging
from evdense.training.stage import run_training
from evdense.training.train import TrainConfig

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
conf = TrainConfig.from_dict({**sm.params.conf, "threads": sm.threads})
run_training(conf, sm.params.run_dir, weights_path=sm.output.weights, workers=sm.threads)
