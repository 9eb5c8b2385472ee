# Simulation of synthetic datasets: ground truth (top), event camera and conventional camera.


# ---- scenes, trajectories, rendering, ground truth ----


rule simulate_groundtruth:
    output:
        gt=directory("results/{dataset}/gt"),
    log:
        "results/{dataset}/logs/simulate_groundtruth.log",
    benchmark:
        "results/{dataset}/benchmarks/simulate_groundtruth.tsv"
    wildcard_constraints:
        dataset=names_regex(SYNTHETIC),
    priority: 1
    threads: 1
    params:
        dataset=dataset_conf,
        simulator=sim_conf,
    script:
        "../scripts/simulate_groundtruth.py"


# ---- event camera and conventional camera ----
# Only synthetic datasets (with `scene`); real recordings get events/events.h5 from `ingest`.


rule simulate_events:
    output:
        events="results/{dataset}/events/events.h5",
    log:
        "results/{dataset}/logs/simulate_events.log",
    benchmark:
        "results/{dataset}/benchmarks/simulate_events.tsv"
    wildcard_constraints:
        dataset=names_regex(SYNTHETIC),
    priority: 1
    threads: 1
    params:
        dataset=dataset_conf,
        simulator=sim_conf,
    script:
        "../scripts/simulate_events.py"


rule simulate_conventional:
    output:
        conventional=directory("results/{dataset}/conventional"),
    log:
        "results/{dataset}/logs/simulate_conventional.log",
    benchmark:
        "results/{dataset}/benchmarks/simulate_conventional.tsv"
    wildcard_constraints:
        dataset=names_regex(SYNTHETIC),
    priority: 1
    threads: 1
    params:
        dataset=dataset_conf,
        simulator=sim_conf,
    script:
        "../scripts/simulate_conventional.py"
