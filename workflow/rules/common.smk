# Helpers shared by the rules: dataset lookup, wildcard constraints, target lists.
# Logic lives in the evdense package; this file only maps config to paths.

import json
import re
from pathlib import Path

from evdense.config import all_datasets, check_config
from evdense.sim.scene import load_scene
from evdense.formats.layout import Layout

check_config(config, base_dir=workflow.basedir, build_scene=load_scene)

DATASETS = all_datasets(config)
LAYOUT = Layout(
    "results"
)  # every path under results/ is spelled by evdense.formats.layout


def repo_relative(path):
    """A relative path that does not exist in the working directory but does in the repository
    (shipped weights, the anchors beside it) is taken from the repository."""
    p = Path(path)
    if p.is_absolute() or p.exists():
        return str(p)
    q = Path(workflow.basedir) / p
    return str(q) if q.exists() else str(p)


config["reconstruct"]["checkpoints"] = {
    k: repo_relative(v) for k, v in config["reconstruct"]["checkpoints"].items()
}
SUMMARY = config["summary_dir"].rstrip("/")
SYNTHETIC = [name for name, ds in DATASETS.items() if "scene" in ds]
RECORDINGS = [name for name, ds in DATASETS.items() if "recording" in ds]


def names_regex(names):
    """A regex matching exactly these names (and nothing when the list is empty)."""
    return "|".join(re.escape(n) for n in names) or "(?!x)x"


wildcard_constraints:
    dataset=names_regex(DATASETS),


def dataset_conf(wildcards):
    """The config entry of the dataset named by the wildcard."""
    return DATASETS[wildcards.dataset]


def sim_conf(wildcards=None):
    return config["simulator"]


def all_targets(wildcards=None):
    """Everything `rule all` asks for: each dataset's products to the textured mesh and, when
    there is ground truth, the metrics table, the figures and the summary. (An input function:
    a recording's image sources are known once it is ingested.)"""
    targets = []
    for name in DATASETS:
        targets += dataset_targets(name)
    if evaluated_datasets():
        targets += [
            f"{SUMMARY}/metrics.csv",
            f"{SUMMARY}/figures",
            f"{SUMMARY}/summary.md",
        ]
    return targets


def evaluated_datasets():
    """Datasets with ground truth to measure against: synthetic scenes, and recordings that carry
    GT poses or APS frames."""
    return SYNTHETIC + [
        name
        for name in RECORDINGS
        if ingest_manifest(name).get("num_poses", 0) > 0
        or ingest_manifest(name).get("num_frames", 0) > 0
    ]


def all_metrics_files():
    """One metrics file per evaluated dataset and image source."""
    return [
        LAYOUT.metrics(name, src)
        for name in evaluated_datasets()
        for src in image_sources(name)
    ]


def default_window_spec():
    """The window spec of the configured default windows (e.g. n25000)."""
    from evdense.events.windows import WindowConfig, window_spec

    return window_spec(WindowConfig.from_dict(config["events"]["window"]))


def window_specs():
    """Window specs of event frames: the configured windows, or one per sweep.num_events."""
    from evdense.events.windows import WindowConfig, window_spec

    sizes = config["sweep"]["num_events"]
    if not sizes:
        return [default_window_spec()]
    base = dict(config["events"]["window"])
    return [
        window_spec(WindowConfig.from_dict({**base, "num_events": n})) for n in sizes
    ]


def event_frame_sources():
    """Names of the event-based frame sources: {method}_{win}_b{bins} over methods, windows and bins."""
    bins_list = config["sweep"]["bins"] or [config["events"]["voxel"]["bins"]]
    return [
        f"{m}_{win}_b{b}"
        for m in config["reconstruct"]["methods"]
        for win in window_specs()
        for b in bins_list
    ]


def dataset_targets(name):
    """Outputs `rule all` asks for, for one dataset: every image source to the textured mesh (a
    source whose SfM fails records "no model" in the stages after it, and the run goes on).
    """
    targets = [
        f"results/{name}/events/summary",
        LAYOUT.gt(name),
        LAYOUT.source_images(name, "conventional"),
    ]
    targets += [LAYOUT.source_images(name, src) for src in event_frame_sources()]
    for src in image_sources(name):
        targets += [LAYOUT.sfm(name, src), LAYOUT.dense_cloud(name, src)]
        targets += mesh_products(name, src)
    if config["evaluate"]["figures"]:
        targets += [LAYOUT.figures(name), LAYOUT.mesh_page(name)]
    return targets


def ingest_manifest(name):
    """What the ingest of a recording found (results/{name}/events/ingest.json); asks Snakemake
    to run the ingest first when it has not run."""
    path = checkpoints.ingest.get(dataset=name).output.manifest
    return json.loads(Path(path).read_text())


def image_sources(name):
    """Image sources reconstructed for a dataset: events through each method, the conventional
    camera (a recording: only when it holds frames), and (synthetic scenes) the sharp GT frames,
    the oracle."""
    sources = list(event_frame_sources())
    if name in SYNTHETIC:
        sources += ["conventional", "gt"]
    elif ingest_manifest(name).get("num_frames", 0) > 0:
        sources.append("conventional")
    return sources


source_images = LAYOUT.source_images  # the rule output holding a source's frames
source_frames_dir = LAYOUT.frames  # the folder of PNG frames + timestamps.txt


def run_labels(dataset, source):
    """Fields that identify a run in the metrics table."""
    ds = DATASETS[dataset]
    kind = source if source in ("gt", "conventional", "oracle") else "events"
    labels = {"dataset": dataset, "source": source, "source_kind": kind}
    if "scene" in ds:
        scene = (
            ds["scene"]
            if isinstance(ds["scene"], str)
            else ds["scene"].get("name", "custom")
        )
        labels.update(
            scene=scene,
            speed=float(ds["speed"]),
            dynamic_range=float(ds["dynamic_range"]),
        )
    if kind == "events":
        method, win, bins = source.rsplit("_", 2)
        labels.update(method=method, window=win, bins=int(bins.lstrip("b")))
    return labels
