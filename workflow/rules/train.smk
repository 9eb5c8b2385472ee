# Training our own reconstruction weights on simulated data (src/evdense/training/).
# The run folder also holds the cached training set (trainset_s<seed>.h5), the resumable
# checkpoints and history.jsonl: they are not declared outputs, so a failed or stopped job keeps
# them and the next run resumes from the latest checkpoint. The shipped weights
# (resources/weights/evfirenet.pt) came from this rule with the default `train` config; copy the
# outputs there to ship a new model.


rule train_model:
    output:
        weights="results/training/{run}/evfirenet.pt",
        metadata="results/training/{run}/evfirenet.json",
    log:
        "results/training/{run}/logs/train_model.log",
    benchmark:
        "results/training/{run}/benchmarks/train_model.tsv"
    threads: 2
    params:
        conf=lambda w: config["train"],
        run_dir=lambda w: f"results/training/{w.run}",
    script:
        "../scripts/train_model.py"
