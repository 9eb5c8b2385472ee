"""Adapter: rule evaluate_source -> evdense.evaluate.stage.run_evaluate."""

from evdense.evaluate.stage import run_evaluate
from evdense.log import setup_logging

setup_logging(snakemake.log[0])
inp = snakemake.input
run_evaluate(
    gt_dir=inp.gt,
    sfm_dir=inp.sfm,
    out_path=snakemake.output.metrics,
    frames_dir=snakemake.params.frames,
    dense_cloud=inp.get("dense"),
    meshes=dict(zip(snakemake.params.mesh_names, inp.get("meshes", []) or [], strict=False)),
    conf=snakemake.params.conf,
    labels=snakemake.params.labels,
    reference_frames=snakemake.params.reference if inp.get("reference") else None,
)
