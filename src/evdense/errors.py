"""The one exception type for bad input: a file, a recording or a config that cannot be used.

Every reader turns a malformed input into :class:`InputError` (a ``ValueError``), whose message
starts with the file's path and says where the problem is (line, byte offset, packet, dataset)
and what is wrong. The command line prints it on one line and exits with status 2.
"""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Malformed or unusable input; the message names the file and the place."""

    def __init__(self, path: str | Path, message: str) -> None:
        self.path = str(path)
        text = str(message)
        super().__init__(text if text.startswith(self.path) else f"{self.path}: {text}")


def as_input_error(path: str | Path, exc: BaseException) -> InputError:
    """``exc`` (any exception a reader or a library under it raised) as an :class:`InputError`.

    Our own errors keep their message (prefixed with the path when it lacks it); foreign ones
    (``BadZipFile``, ``zlib.error``, ``struct.error``, ``KeyError``, ...) are described by their
    type and message.
    """
    if isinstance(exc, InputError):
        return exc
    if isinstance(exc, ValueError | FileNotFoundError):
        msg = str(exc)
    else:
        detail = str(exc) or repr(exc)
        msg = f"unreadable ({type(exc).__name__}: {detail})"
    err = InputError(path, msg)
    err.__cause__ = exc
    return err
