# Windows of events, voxel grids and the per-dataset event summary (src/evdense/events/).
# The window spec in file names ({win}: n25000, dt50ms, n25000-max100ms, ...-ov0.5) fully
# describes the windows; config["events"]["window"] only chooses the default spec
# (evdense.events.windows.window_spec) that common.smk asks for.

from evdense.events.windows import WINDOW_SPEC_REGEX


rule make_windows:
    input:
        events="results/{dataset}/events/events.h5",
    output:
        windows="results/{dataset}/events/windows_{win}.h5",
    log:
        "results/{dataset}/logs/make_windows/{win}.log",
    benchmark:
        "results/{dataset}/benchmarks/make_windows/{win}.tsv"
    wildcard_constraints:
        win=WINDOW_SPEC_REGEX,
    priority: 1
    threads: 1
    script:
        "../scripts/make_windows.py"


rule make_voxels:
    input:
        events="results/{dataset}/events/events.h5",
        windows="results/{dataset}/events/windows_{win}.h5",
    output:
        voxels="results/{dataset}/events/voxels_{win}_b{bins}.h5",
    log:
        "results/{dataset}/logs/make_voxels/{win}_b{bins}.log",
    benchmark:
        "results/{dataset}/benchmarks/make_voxels/{win}_b{bins}.tsv"
    wildcard_constraints:
        win=WINDOW_SPEC_REGEX,
        bins=r"\d+",
    priority: 1
    threads: 1
    params:
        conf=lambda w: config["events"]["voxel"],
    script:
        "../scripts/make_voxels.py"


rule summarize_events:
    input:
        events="results/{dataset}/events/events.h5",
    output:
        summary=directory("results/{dataset}/events/summary"),
    log:
        "results/{dataset}/logs/summarize_events/summary.log",
    benchmark:
        "results/{dataset}/benchmarks/summarize_events/summary.tsv"
    threads: 1
    params:
        summary=lambda w: config["events"]["summary"],
        window=lambda w: config["events"]["window"],
    script:
        "../scripts/summarize_events.py"
