# Gathering, figures and the report: all runs in one table, the paper's figures, a summary.
# `snakemake --report report.html` turns the outputs marked report(...) into a readable account.


report: "../report/workflow.rst"


rule gather_metrics:
    input:
        metrics=lambda w: all_metrics_files(),
    output:
        csv=report(
            f"{SUMMARY}/metrics.csv",
            caption="../report/metrics_table.rst",
            category="Metrics",
        ),
        md=f"{SUMMARY}/metrics.md",
    log:
        f"{SUMMARY}/logs/gather_metrics.log",
    benchmark:
        f"{SUMMARY}/benchmarks/gather_metrics.tsv"
    script:
        "../scripts/gather_metrics.py"


rule plot_figures:
    input:
        csv=f"{SUMMARY}/metrics.csv",
    output:
        figures=report(
            directory(f"{SUMMARY}/figures"),
            patterns=["{name}.png"],
            caption="../report/figures.rst",
            category="Figures",
        ),
    log:
        f"{SUMMARY}/logs/plot_figures.log",
    benchmark:
        f"{SUMMARY}/benchmarks/plot_figures.tsv"
    script:
        "../scripts/plot_figures.py"


rule write_summary:
    input:
        csv=f"{SUMMARY}/metrics.csv",
    output:
        md=report(
            f"{SUMMARY}/summary.md",
            caption="../report/summary.rst",
            category="Summary",
        ),
        config=f"{SUMMARY}/config.yaml",
    log:
        f"{SUMMARY}/logs/write_summary.log",
    params:
        config=lambda w: config,
    script:
        "../scripts/write_summary.py"
