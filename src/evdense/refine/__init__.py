"""Photometric refinement of a surface mesh against calibrated images: the algorithm in
:mod:`~evdense.refine.photometric`, the stage function :func:`~evdense.refine.stage.run_refine`."""

from evdense.refine.photometric import RefineConfig, refine_vertices
from evdense.refine.stage import run_refine

__all__ = ["RefineConfig", "refine_vertices", "run_refine"]
