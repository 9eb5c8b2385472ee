"""Readers for real event recordings, their validation, and the ``ingest`` stage.

One module per format family (``text``, ``h5formats``, ``aedat4``, ``rosbag``, ``prophesee``,
``numpy_io``); :func:`open_recording` picks the reader from the file (``detect``);
:func:`validate_stream` checks and normalises the stream; :func:`ingest_recording` writes the
canonical event file and the recording's frames, calibration and ground truth.
"""

from evdense.io.base import Frame, RawEvents, Recording, Trajectory
from evdense.io.detect import FORMATS, detect_format, open_recording
from evdense.io.ingest import IngestConfig, IngestResult, ingest_recording
from evdense.io.validate import ValidationConfig, ValidationReport, validate_stream

__all__ = [
    "FORMATS",
    "Frame",
    "IngestConfig",
    "IngestResult",
    "RawEvents",
    "Recording",
    "Trajectory",
    "ValidationConfig",
    "ValidationReport",
    "detect_format",
    "ingest_recording",
    "open_recording",
    "validate_stream",
]
