# Intensity reconstruction: voxel grids (networks) or events (classical baselines) to a folder
# of frames per preset (src/evdense/recon/). The {method} wildcard names a preset of
# config["reconstruct"]["presets"] (or a bare method name); the folder name carries the preset,
# the window spec and the bins, so that sweeps coexist.

from dataclasses import asdict

from evdense.events.windows import WINDOW_SPEC_REGEX
from evdense.recon.config import BASELINES, resolve_config


def recon_conf(wildcards):
    """The resolved options of the preset named by {method}, as a plain dict."""
    return asdict(resolve_config(config["reconstruct"], wildcards.method))


def recon_inputs(wildcards):
    """Voxels always; the events for baselines; the weights for networks; conventional frames
    for the complementary filter."""
    conf = resolve_config(config["reconstruct"], wildcards.method)
    d = wildcards.dataset
    inputs = {
        "voxels": f"results/{d}/events/voxels_{wildcards.win}_b{wildcards.bins}.h5"
    }
    if conf.method in BASELINES:
        inputs["events"] = f"results/{d}/events/events.h5"
        if conf.method == "highpass" and conf.use_conventional_frames:
            inputs["conventional"] = f"results/{d}/conventional"
    else:
        inputs["weights"] = conf.checkpoint
    return inputs


RECON_PRESETS = sorted(
    set(config["reconstruct"]["presets"])
    | set(config["reconstruct"]["checkpoints"])
    | set(BASELINES)
)


rule reconstruct_frames:
    input:
        unpack(recon_inputs),
    output:
        frames=directory("results/{dataset}/frames/{method}_{win}_b{bins}"),
    log:
        "results/{dataset}/logs/reconstruct_frames/{method}_{win}_b{bins}.log",
    benchmark:
        "results/{dataset}/benchmarks/reconstruct_frames/{method}_{win}_b{bins}.tsv"
    wildcard_constraints:
        method=names_regex(RECON_PRESETS),
        win=WINDOW_SPEC_REGEX,
        bins=r"\d+",
    priority: 1
    threads: 2
    params:
        conf=recon_conf,
    script:
        "../scripts/reconstruct_frames.py"
