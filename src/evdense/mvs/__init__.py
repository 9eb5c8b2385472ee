"""Multi-view stereo: our PatchMatch stereo in PyTorch, fused into a dense point cloud.

Modules: :mod:`~evdense.mvs.patchmatch` (the depth/normal estimation), :mod:`~evdense.mvs.workspace`
(undistortion, COLMAP dense workspace, source views), :mod:`~evdense.mvs.maps_io` (COLMAP map files,
previews), :mod:`~evdense.mvs.fusion` (point cloud), :mod:`~evdense.mvs.oracle` (workspace from
ground truth, evaluation), :mod:`~evdense.mvs.stage` (the stage function :func:`run_mvs`).
"""

from evdense.mvs.fusion import FusionConfig
from evdense.mvs.patchmatch import FilterConfig, PatchMatchConfig, estimate_depth_map
from evdense.mvs.stage import MVSConfig, run_mvs
from evdense.mvs.workspace import ViewSelectionConfig

__all__ = [
    "FilterConfig",
    "FusionConfig",
    "MVSConfig",
    "PatchMatchConfig",
    "ViewSelectionConfig",
    "estimate_depth_map",
    "run_mvs",
]
