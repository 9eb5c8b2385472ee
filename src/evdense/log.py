"""One named logger for the whole package, and progress that shows up in Snakemake log files."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TypeVar

LOGGER_NAME = "evdense"
_FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"

T = TypeVar("T")


def get_logger(name: str | None = None) -> logging.Logger:
    """Return the package logger, or a child of it (``evdense.<name>``)."""
    return logging.getLogger(LOGGER_NAME if name is None else f"{LOGGER_NAME}.{name}")


def setup_logging(log_file: str | Path | None = None, level: int = logging.INFO) -> logging.Logger:
    """Send evdense's log records to stderr and, when given, to ``log_file`` (appended).

    With a ``log_file``, an exception that ends the process is written there too (Snakemake
    points at a failed job's log file), then shown on stderr as usual. Safe to call more than
    once: earlier handlers installed by this function are replaced.
    """
    logger = get_logger()
    logger.setLevel(level)
    for h in list(logger.handlers):
        if getattr(h, "_evdense", False):
            logger.removeHandler(h)
    handlers: list[logging.Handler] = [logging.StreamHandler(sys.stderr)]
    if log_file is not None:
        Path(log_file).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(log_file))
    for h in handlers:
        h.setFormatter(logging.Formatter(_FORMAT))
        h._evdense = True  # type: ignore[attr-defined]
        logger.addHandler(h)
    logger.propagate = False
    if log_file is not None:
        _log_uncaught_exceptions(logger)
    return logger


def _log_uncaught_exceptions(logger: logging.Logger) -> None:
    shown = getattr(sys.excepthook, "_evdense_shown", sys.excepthook)

    def hook(kind, value, tb) -> None:
        for h in logger.handlers:
            if isinstance(h, logging.FileHandler) and getattr(h, "_evdense", False):
                h.handle(logger.makeRecord(logger.name, logging.CRITICAL, "", 0,
                                           f"stopped by {kind.__name__}: {value}", None,
                                           (kind, value, tb)))  # fmt: skip
        shown(kind, value, tb)

    hook._evdense_shown = shown  # type: ignore[attr-defined]
    sys.excepthook = hook


def progress(
    items: Iterable[T],
    total: int | None = None,
    desc: str = "",
    logger: logging.Logger | None = None,
    every_s: float = 10.0,
) -> Iterator[T]:
    """Yield ``items`` and log ``desc: i/total (rate/s, eta)`` at most every ``every_s`` seconds.

    Log lines (not a terminal bar) so that progress is readable in Snakemake's log files.
    """
    logger = logger or get_logger()
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    start = last = time.monotonic()
    i = 0
    for i, item in enumerate(items, 1):
        yield item
        now = time.monotonic()
        if now - last >= every_s:
            last = now
            rate = i / max(now - start, 1e-9)
            if total:
                eta = (total - i) / max(rate, 1e-9)
                logger.info("%s: %d/%d (%.1f/s, eta %.0f s)", desc, i, total, rate, eta)
            else:
                logger.info("%s: %d (%.1f/s)", desc, i, rate)
    elapsed = time.monotonic() - start
    if elapsed >= every_s:
        logger.info("%s: done, %d in %.1f s", desc, i, elapsed)
