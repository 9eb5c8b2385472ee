"""Intensity reconstruction: events (voxel grids) to frames with recurrent networks or classical filters.

Submodules: ``networks`` (FireNet, FireNet+, E2VID), ``checkpoints`` (our format and the published
ones, loaded safely), ``postprocess`` (normalisation, tone mapping, frame folders), ``baselines``
(integration, high-pass filter), ``config`` (stage options), ``inference`` (a network run window by window) and ``stage``
(the stage function :func:`run_recon`, also ``python -m evdense.recon``);
training lives in :mod:`evdense.training`. Names are imported lazily, so that
``evdense.recon.config`` can be used without importing torch.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "E2VID": "networks",
    "FireNet": "networks",
    "FireNetPlus": "networks",
    "build_network": "networks",
    "CheckpointError": "checkpoints",
    "LoadedCheckpoint": "checkpoints",
    "load_checkpoint": "checkpoints",
    "save_checkpoint": "checkpoints",
    "LogIntensityFilter": "baselines",
    "ReconstructConfig": "config",
    "resolve_config": "config",
    "NetworkReconstructor": "inference",
    "run_recon": "stage",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"evdense.recon.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'evdense.recon' has no attribute {name!r}")
