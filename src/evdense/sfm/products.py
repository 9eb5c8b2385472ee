"""An SfM output folder as the later stages read it: its trajectory, and the record of a failed
run (``stats.json`` with ``failed: true``, see :mod:`evdense.formats.status`)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from evdense.formats.files import write_json_atomic
from evdense.formats.status import STATS_NAME, is_failed
from evdense.log import get_logger
from evdense.sfm.config import SfmError

log = get_logger("sfm")


def write_failed_sfm(out_dir: str | Path, error: SfmError) -> Path:
    """Write an SfM output folder that records a failure: ``stats.json`` with ``failed: true``,
    the error message and the diagnostics, ``diagnostics.json``, and nothing else (no model, no
    trajectory); the failed run's ``<out_dir>.partial`` working folder is removed."""
    out_dir = Path(out_dir)
    diagnostics: dict[str, Any] = {}
    if error.diagnostics_path is not None and Path(error.diagnostics_path).exists():
        diagnostics = json.loads(Path(error.diagnostics_path).read_text())
    tmp = out_dir.with_name(out_dir.name + ".failed.partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    message = str(error)
    if error.diagnostics_path is not None:  # the diagnostics move into the recorded folder
        message = message.replace(str(error.diagnostics_path), str(out_dir / "diagnostics.json"))
        write_json_atomic(tmp / "diagnostics.json", diagnostics)
    stats = {
        "failed": True,
        "error": message,
        "num_registered": 0,
        "registered_fraction": 0.0,
        "diagnostics": diagnostics,
    }
    write_json_atomic(tmp / "stats.json", stats)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    tmp.rename(out_dir)
    work = out_dir.with_name(out_dir.name + ".partial")  # the failed run's working folder
    if work.exists():
        shutil.rmtree(work)
    log.warning("SfM failed, recorded in %s: %s", out_dir, message)
    return out_dir


def sfm_failed(sfm_dir: str | Path) -> bool:
    """True when an SfM output folder records a failure (see :func:`write_failed_sfm`)."""
    return is_failed(Path(sfm_dir) / STATS_NAME)


def read_sfm_trajectory(sfm_dir: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps ``(N,)`` (s) and camera-to-world poses ``(N, 4, 4)`` of an SfM output folder
    (SfM frame and scale)."""
    from evdense.poses import read_tum

    return read_tum(Path(sfm_dir) / "trajectory.txt")
