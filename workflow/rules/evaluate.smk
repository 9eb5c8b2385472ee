# Evaluation (src/evdense/evaluate/): every image source of every synthetic dataset against its
# ground truth, one metrics file per run, all runs gathered into one table.


def evaluate_inputs(wildcards):
    d, s = wildcards.dataset, wildcards.source
    return {
        "gt": f"results/{d}/gt",
        "sfm": f"results/{d}/sfm/{s}",
        "images": source_images(d, s),
        "dense": f"results/{d}/mvs/{s}/fused.ply",
        "meshes": mesh_products(d, s),
    }


rule evaluate_source:
    input:
        unpack(evaluate_inputs),
    output:
        metrics="results/{dataset}/eval/{source}/metrics.json",
    log:
        "results/{dataset}/logs/evaluate_source/{source}.log",
    benchmark:
        "results/{dataset}/benchmarks/evaluate_source/{source}.tsv"
    wildcard_constraints:
        dataset=names_regex(SYNTHETIC),
    threads: 1
    params:
        conf=lambda w: config["evaluate"],
        labels=lambda w: run_labels(w.dataset, w.source),
        frames=lambda w: source_frames_dir(w.dataset, w.source),
        mesh_names=lambda w: list(mesh_product_names()),
    script:
        "../scripts/evaluate_source.py"
