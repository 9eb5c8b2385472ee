"""Snakemake adapter of rule make_voxels: events.h5 + windows_<spec>.h5 -> voxels_<spec>_b<B>.h5."""

from evdense.events.voxel import VoxelConfig, make_voxels
from evdense.log import setup_logging

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
conf = VoxelConfig(**{**sm.params.conf, "bins": int(sm.wildcards.bins)})
make_voxels(sm.input.events, sm.input.windows, sm.output.voxels, conf)
