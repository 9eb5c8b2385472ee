# Multi-view stereo (src/evdense/mvs/): a sparse model and its frames -> dense workspace (COLMAP
# layout), depth and normal maps (our PatchMatch in PyTorch), fused cloud.
# {source} names an image source: gt (sharp GT frames), conventional (the frame camera), a
# reconstructed-frames folder (<method>_<spec>_b<B>), or oracle: GT poses, intrinsics and frames
# with sparse points from GT depth, i.e. the oracle check of the stereo without SfM.
# Maps are written one at a time and reused when present: an interrupted job resumes (the
# workspace folder is not a declared output, so Snakemake does not delete it).


def mvs_inputs(wildcards):
    """The folder holding the sparse model (sparse/0) and the rule output holding the frames."""
    d, s = wildcards.dataset, wildcards.source
    model = f"results/{d}/oracle" if s == "oracle" else f"results/{d}/sfm/{s}"
    return {"model": model, "images": source_images(d, s)}


rule build_oracle_model:
    input:
        gt="results/{dataset}/gt",
    output:
        model=directory("results/{dataset}/oracle"),
    log:
        "results/{dataset}/logs/build_oracle_model.log",
    benchmark:
        "results/{dataset}/benchmarks/build_oracle_model.tsv"
    wildcard_constraints:
        dataset=names_regex(SYNTHETIC),
    threads: 1
    params:
        conf=lambda w: config["mvs"]["oracle"],
    script:
        "../scripts/build_oracle_model.py"


rule run_mvs:
    input:
        unpack(mvs_inputs),
    output:
        fused="results/{dataset}/mvs/{source}/fused.ply",
        stats="results/{dataset}/mvs/{source}/stats.json",
    log:
        "results/{dataset}/logs/run_mvs/{source}.log",
    benchmark:
        "results/{dataset}/benchmarks/run_mvs/{source}.tsv"
    wildcard_constraints:
        source=r"[A-Za-z0-9_\-]+",
    priority: 1
    threads: 2
    resources:
        gpu=1,
    params:
        frames=lambda w: source_frames_dir(w.dataset, w.source),
        conf=lambda w: {k: v for k, v in config["mvs"].items() if k != "oracle"},
    script:
        "../scripts/run_mvs.py"


rule evaluate_mvs_oracle:
    input:
        fused="results/{dataset}/mvs/oracle/fused.ply",
        gt="results/{dataset}/gt",
    output:
        evaluation="results/{dataset}/mvs/oracle_evaluation.json",
    log:
        "results/{dataset}/logs/evaluate_mvs_oracle.log",
    benchmark:
        "results/{dataset}/benchmarks/evaluate_mvs_oracle.tsv"
    wildcard_constraints:
        dataset=names_regex(SYNTHETIC),
    threads: 1
    params:
        threshold=lambda w: config["mvs"]["oracle"]["threshold"],
    script:
        "../scripts/evaluate_mvs_oracle.py"
