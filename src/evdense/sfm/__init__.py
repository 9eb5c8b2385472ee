"""Structure from motion on a frames folder with pycolmap: SIFT, matching, incremental mapping.

One public stage function, :func:`run_sfm`, turns a frames folder (``000000.png ...`` plus
``timestamps.txt`` with lines ``index t_seconds``) into one output folder:

- ``sparse/0/*.bin`` (COLMAP binary model) and ``sparse/0_text/*.txt`` (opens in the COLMAP GUI),
- ``database.db`` (features, matches, verified two-view geometries),
- ``points3D.ply`` (sparse points), ``trajectory.txt`` (TUM, camera-to-world of registered frames,
  SfM frame and scale), ``selected_frames.txt`` (``index name t_seconds`` of the frames given to SfM),
- ``stats.json`` (registration, points, track length, reprojection error, intrinsics, time per step).

The folder is written as ``<out>.partial`` and renamed when complete. When too few frames register,
``<out>.partial/diagnostics.json`` is kept (features per image, verified pairs) and :class:`SfmError`
names it.

pycolmap's own option objects are configured from plain dicts (``extraction``, ``matching``,
``verification``, ``pairing``, ``mapping``): keys are their attribute names, nested dicts (or dotted
keys) reach sub-objects, strings name enum members. Unknown names raise ``ValueError`` naming the key.

Pixel convention: COLMAP puts the centre of the top-left pixel at (0.5, 0.5), evdense at (0, 0).
Intrinsics going into and coming out of COLMAP are shifted by 0.5 px here; ``stats.json`` reports
both conventions.
"""

from evdense.sfm.config import (
    CAMERA_MODELS,
    COLMAP_LOG_LEVELS,
    DEVICES,
    MATCHERS,
    SELECT_METHODS,
    SfmConfig,
    SfmError,
)
from evdense.sfm.options import set_options
from evdense.sfm.products import read_sfm_trajectory, sfm_failed, write_failed_sfm
from evdense.sfm.select import select_frames
from evdense.sfm.stage import run_sfm

__all__ = [
    "CAMERA_MODELS",
    "COLMAP_LOG_LEVELS",
    "DEVICES",
    "MATCHERS",
    "SELECT_METHODS",
    "SfmConfig",
    "SfmError",
    "read_sfm_trajectory",
    "run_sfm",
    "select_frames",
    "set_options",
    "sfm_failed",
    "write_failed_sfm",
]
