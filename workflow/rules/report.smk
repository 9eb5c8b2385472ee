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


def dataset_figure_sources(dataset):
    """Per image source, the products its pictures are drawn from (SourceFiles fields)."""
    evaluated = dataset in evaluated_datasets()
    out = {}
    for src in image_sources(dataset):
        mesh, refined, textured = mesh_products(dataset, src)
        out[src] = {
            "frames": source_frames_dir(dataset, src),
            "sfm": LAYOUT.sfm(dataset, src),
            "dense": LAYOUT.dense_cloud(dataset, src),
            "refined": refined,
            "textured": textured,
            "metrics": LAYOUT.metrics(dataset, src) if evaluated else None,
        }
    return out


def dataset_figure_inputs(wildcards):
    """Every file the dataset's pictures read: declared, so a changed product redraws them."""
    d = wildcards.dataset
    files = [
        source_images(d, src) for src in image_sources(d)
    ]  # rule outputs holding the frames
    for src, f in dataset_figure_sources(d).items():
        files += [f["sfm"], f["dense"], f["refined"], f["textured"]]
        files += [f["metrics"]] if f["metrics"] else []
    return {"events": LAYOUT.events(d), "gt": LAYOUT.gt(d), "products": files}


rule plot_dataset:
    input:
        unpack(dataset_figure_inputs),
    output:
        figures=report(
            directory(LAYOUT.figures("{dataset}")),
            patterns=["{name}.png"],
            caption="../report/dataset_figures.rst",
            category="Reconstructions",
            subcategory="{dataset}",
        ),
        page=report(
            LAYOUT.mesh_page("{dataset}"),
            caption="../report/meshes_page.rst",
            category="Reconstructions",
            subcategory="{dataset}",
        ),
    log:
        "results/{dataset}/logs/plot_dataset.log",
    benchmark:
        "results/{dataset}/benchmarks/plot_dataset.tsv"
    threads: 1
    params:
        sources=lambda w: dataset_figure_sources(w.dataset),
        conf=lambda w: config["evaluate"],
    script:
        "../scripts/plot_dataset.py"


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
