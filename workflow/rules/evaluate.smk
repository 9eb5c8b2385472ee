# Evaluation (src/evdense/evaluate/): every image source of every dataset with ground truth against
# it, one metrics file per run, all runs gathered into one table. A synthetic scene has it all; a
# recording is measured by what it carries (GT poses: ATE/RPE; APS frames: the event frames
# against the nearest one).


def evaluate_inputs(wildcards):
    d, s = wildcards.dataset, wildcards.source
    inputs = {
        "gt": LAYOUT.gt(d),
        "sfm": LAYOUT.sfm(d, s),
        "images": source_images(d, s),
        "dense": LAYOUT.dense_cloud(d, s),
        "meshes": mesh_products(d, s),
    }
    if d in RECORDINGS and "conventional" in image_sources(d):
        inputs["reference"] = source_images(d, "conventional")  # its APS frames
    return inputs


rule evaluate_source:
    input:
        unpack(evaluate_inputs),
    output:
        metrics="results/{dataset}/eval/{source}/metrics.json",
    log:
        "results/{dataset}/logs/evaluate_source/{source}.log",
    benchmark:
        "results/{dataset}/benchmarks/evaluate_source/{source}.tsv"
    threads: 1
    params:
        conf=lambda w: config["evaluate"],
        labels=lambda w: run_labels(w.dataset, w.source),
        frames=lambda w: source_frames_dir(w.dataset, w.source),
        mesh_names=lambda w: list(mesh_product_names()),
        reference=lambda w: (
            source_frames_dir(w.dataset, "conventional")
            if w.dataset in RECORDINGS
            else None
        ),
    script:
        "../scripts/evaluate_source.py"
