"""Writing a file so that a reader never sees half of it: write beside it, then rename.

Every stage writes its JSON, text and binary products through these helpers: the data go to
``<name>.partial`` in the same folder and :func:`os.replace` moves them over ``path`` in one step,
so an interrupted run leaves the old file or none, never a truncated one that looks complete.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Self


def partial_path(path: str | Path, keep_suffix: bool = False) -> Path:
    """The temporary name a product is written under: ``<name>.partial`` beside it, or
    ``<stem>.partial<suffix>`` with ``keep_suffix`` (for writers that choose the format by the
    file's extension, as imageio and open3d do)."""
    path = Path(path)
    if keep_suffix:
        return path.with_name(f"{path.stem}.partial{path.suffix}")
    return path.with_name(path.name + ".partial")


@contextmanager
def atomic_path(path: str | Path, keep_suffix: bool = False) -> Iterator[Path]:
    """Yield the temporary path to write ``path`` to; renamed to ``path`` when the block exits
    cleanly, deleted when it raises. Parent folders are created."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_path(path, keep_suffix)
    try:
        yield tmp
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)


def write_atomic(path: str | Path, write: Callable[[Path], Any], keep_suffix: bool = False) -> Path:
    """Call ``write(tmp)`` for a temporary path, then move it to ``path``; returns ``path``."""
    with atomic_path(path, keep_suffix) as tmp:
        write(tmp)
    return Path(path)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def write_json_atomic(
    path: str | Path, data: Any, indent: int | None = 2, default: Callable | None = str
) -> Path:
    """Write ``data`` as JSON to ``path`` atomically (``default`` converts what JSON lacks)."""
    return write_text_atomic(path, json.dumps(data, indent=indent, default=default))


def read_json(path: str | Path) -> Any:
    """Read a JSON file; ``ValueError`` naming the file when it is not valid JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None


class Closing:
    """``with Reader(...) as r:`` closes ``r`` on the way out (subclasses define ``close``)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release what is open (nothing by default)."""


class CompleteOrAbsent:
    """A writer whose product is complete or absent: leaving its ``with`` block normally calls
    ``close()`` (which finishes the product), leaving it by an exception calls ``abort()``
    (which deletes what was written)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def close(self) -> object:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError
