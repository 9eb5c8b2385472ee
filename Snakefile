# evdense: event-camera recordings to dense, textured 3D meshes, measured against ground truth.
# Run: snakemake --cores 2 [--configfile config/other.yaml]. See README.md and config/README.md.

from snakemake.utils import min_version

from evdense.config import validate_config

min_version("9.0")


# The default config applies only when none is given on the command line, so that
# `--configfile config/experiment.yaml` replaces it instead of being merged into it.
if not config:

    configfile: "config/config.yaml"


# Our validator (the schema, defaults filled in) names the offending key as a dotted path.
validate_config(config, workflow.source_path("workflow/schemas/config.schema.yaml"))


# Scheduling: the rules up to MVS (simulation, windows, voxels, frames, SfM, MVS; SfM, MVS and
# the network take two threads) have priority 1, the one-thread mesh and evaluation rules 0. With
# two cores, every two-thread job then runs as soon as it can, and the one-thread jobs pair up
# behind them instead of leaving a core idle beside a lone one (room_fast: see docs/benchmarks.md).
include: "workflow/rules/common.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/ingest.smk"
include: "workflow/rules/events.smk"
include: "workflow/rules/reconstruct.smk"
include: "workflow/rules/sfm.smk"
include: "workflow/rules/mvs.smk"
include: "workflow/rules/mesh.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/train.smk"


rule all:
    default_target: True
    input:
        all_targets,
