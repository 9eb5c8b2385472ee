# Real recordings (datasets with `recording`) -> the canonical event file, plus the recording's
# conventional frames, calibration and ground truth when it has them (src/evdense/io/).
# The conventional/ and gt/ folders are always created (possibly empty): Snakemake has no optional
# outputs, so results/{dataset}/events/ingest.json lists what was found (null where absent).
# events.h5 has the same path as simulate_events' output; the dataset wildcard constraints
# (RECORDINGS here, SYNTHETIC there) keep the two rules apart. A checkpoint: what the recording
# holds (frames or not) decides its image sources (common.smk: image_sources).


def ingest_inputs(wildcards):
    """The recording, and the calibration and GT files when the dataset names them."""
    ds = DATASETS[wildcards.dataset]
    inputs = {"recording": ds["recording"]}
    if ds.get("calibration"):
        inputs["calibration"] = ds["calibration"]
    for key in ("gt_mesh", "gt_trajectory", "gt_depth"):
        if ds.get(key):
            inputs[key] = ds[key]
    return inputs


checkpoint ingest:
    input:
        unpack(ingest_inputs),
    output:
        events="results/{dataset}/events/events.h5",
        conventional=directory("results/{dataset}/conventional"),
        gt=directory("results/{dataset}/gt"),
        manifest="results/{dataset}/events/ingest.json",
    log:
        "results/{dataset}/logs/ingest.log",
    benchmark:
        "results/{dataset}/benchmarks/ingest.tsv"
    wildcard_constraints:
        dataset=names_regex(RECORDINGS),
    threads: 1
    params:
        dataset=dataset_conf,
        conf=lambda wildcards: config.get("ingest", {}),
    script:
        "../scripts/ingest.py"
