"""The files that pass between stages, each defined once: who writes it, who reads it, what it holds.

- :mod:`evdense.formats.frames`: a frames folder (PNGs + ``timestamps.txt``), written by the
  simulator, the recording's ingest and the reconstruction, read by SfM, MVS and the evaluation.
"""
