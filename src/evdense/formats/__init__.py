"""The files that pass between stages, each defined once: who writes it, who reads it, what it holds.

- :mod:`evdense.formats.frames`: a frames folder (PNGs + ``timestamps.txt``), written by the
  simulator, the recording's ingest and the reconstruction, read by SfM, MVS and the evaluation;
- :mod:`evdense.formats.files`: atomic writes (``<name>.partial``, then rename) and JSON;
- :mod:`evdense.formats.status`: the failed-stage record (``stats.json`` with ``failed: true``)
  and the empty products the stages after a failed SfM write.
"""
