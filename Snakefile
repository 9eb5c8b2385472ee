# evdense: event-camera recordings to dense, textured 3D meshes, measured against ground truth.
# Run: snakemake --cores 2 [--configfile config/other.yaml]. See README.md and config/README.md.

from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/ingest.smk"
include: "workflow/rules/events.smk"
include: "workflow/rules/reconstruct.smk"
include: "workflow/rules/sfm.smk"


rule all:
    input:
        all_targets(),
    default_target: True
