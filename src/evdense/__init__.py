"""evdense: event-camera recordings to dense, textured 3D meshes, measured against ground truth."""

from evdense.log import get_logger

__version__ = "0.1.0"
__all__ = ["__version__", "get_logger"]
