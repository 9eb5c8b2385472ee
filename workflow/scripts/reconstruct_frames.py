"""Snakemake adapter of rule reconstruct_frames: voxels (+ events) -> frames/<preset>_<spec>_b<B>/."""

import os

# Before torch loads OpenMP: waiting threads sleep instead of spinning. On a busy machine, spinning
# threads of one job starve its own other threads (measured: 10x slower frames at 2 threads).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from evdense.log import setup_logging  # noqa: E402
from evdense.recon.config import ReconstructConfig  # noqa: E402
from evdense.recon.stage import run_recon  # noqa: E402

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
run_recon(
    sm.input.voxels,
    sm.output.frames,
    ReconstructConfig.from_dict(sm.params.conf),
    events_path=sm.input.get("events"),
    reference_frames_dir=f"{sm.input.conventional}/frames"
    if "conventional" in sm.input.keys()
    else None,
    num_threads=sm.threads,
)
