# Structure from motion (src/evdense/sfm.py): a frames folder -> COLMAP model, database, sparse
# points, trajectory and statistics in results/{dataset}/sfm/{source}/.
# {source} names an image source: gt (sharp GT frames), conventional (the frame camera) or a
# reconstructed-frames folder results/{dataset}/frames/{source} (e.g. firenet_n25000_b5).
# On failure (too few registered frames) results/{dataset}/sfm/{source}.partial/diagnostics.json
# says why; Snakemake does not delete it since it is not a declared output.


def sfm_inputs(wildcards):
    """The rule output holding the frames, and the GT folder where the calibration comes from:
    config sfm.calibration `dataset` (a synthetic scene's GT intrinsics, a recording's own) or
    `auto` on a recording (its gt/intrinsics.yaml when ingest found one; the script decides).
    """
    d = wildcards.dataset
    inputs = {"images": source_images(d, wildcards.source)}
    cal = config["sfm"]["calibration"]
    if (cal == "dataset" and d in SYNTHETIC) or (
        cal in ("auto", "dataset") and d in RECORDINGS
    ):
        inputs["gt"] = f"results/{d}/gt"
    return inputs


def sfm_conf(wildcards):
    """The sfm config section with `calibration: dataset` resolved to a file, less the keys that
    do not change a finished model (on_failure, colmap_log_level: the script reads them from the
    config), so that flipping them reruns nothing already made."""
    conf = {
        k: v
        for k, v in config["sfm"].items()
        if k not in ("on_failure", "colmap_log_level")
    }
    d = wildcards.dataset
    if conf["calibration"] == "dataset" and d in SYNTHETIC:
        conf["calibration"] = f"results/{d}/gt/intrinsics.yaml"
    elif conf["calibration"] == "auto" and d in SYNTHETIC:
        conf["calibration"] = None
    return conf


rule run_sfm:
    input:
        unpack(sfm_inputs),
    output:
        model=directory("results/{dataset}/sfm/{source}"),
    log:
        "results/{dataset}/logs/run_sfm/{source}.log",
    benchmark:
        "results/{dataset}/benchmarks/run_sfm/{source}.tsv"
    wildcard_constraints:
        source=r"[A-Za-z0-9_\-]+",
    priority: 1
    threads: 2
    params:
        frames=lambda w: source_frames_dir(w.dataset, w.source),
        conf=sfm_conf,
    script:
        "../scripts/run_sfm.py"
