"""Snakemake adapter of rule ingest: a real recording -> events.h5, conventional/, gt/, ingest.json."""

from evdense.io.ingest import IngestConfig, ingest_recording
from evdense.log import setup_logging

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
ds = sm.params.dataset
ingest_recording(
    sm.input.recording,
    sm.output.events,
    conventional_dir=sm.output.conventional,
    gt_dir=sm.output.gt,
    manifest_out=sm.output.manifest,
    fmt=ds.get("format", "auto"),
    calibration=sm.input.get("calibration"),
    width=ds.get("width"),
    height=ds.get("height"),
    config=IngestConfig.from_dict(sm.params.conf),
    reader_options={"topic": ds["topic"]} if ds.get("topic") else None,
    gt_mesh=sm.input.get("gt_mesh"),
    gt_trajectory=sm.input.get("gt_trajectory"),
    gt_depth=sm.input.get("gt_depth"),
)
