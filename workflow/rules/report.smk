# Gathering, figures and the report: all runs in one table, the paper's figures, a summary.
# `snakemake --report report.html` turns the outputs marked report(...) into a readable account.


report: "../report/workflow.rst"


rule gather_metrics:
    input:
        metrics=lambda w: all_metrics_files(),
    output:
        csv=report(
            "results/summary/metrics.csv",
            caption="../report/metrics_table.rst",
            category="Metrics",
        ),
        md="results/summary/metrics.md",
    log:
        "results/summary/logs/gather_metrics.log",
    benchmark:
        "results/summary/benchmarks/gather_metrics.tsv"
    script:
        "../scripts/gather_metrics.py"


rule plot_figures:
    input:
        csv="results/summary/metrics.csv",
    output:
        figures=report(
            directory("results/summary/figures"),
            patterns=["{name}.png"],
            caption="../report/figures.rst",
            category="Figures",
        ),
    log:
        "results/summary/logs/plot_figures.log",
    benchmark:
        "results/summary/benchmarks/plot_figures.tsv"
    script:
        "../scripts/plot_figures.py"


rule write_summary:
    input:
        csv="results/summary/metrics.csv",
    output:
        md=report(
            "results/summary/summary.md",
            caption="../report/summary.rst",
            category="Summary",
        ),
        config="results/summary/config.yaml",
    log:
        "results/summary/logs/write_summary.log",
    params:
        config=lambda w: config,
    script:
        "../scripts/write_summary.py"
