"""A frames folder: the images a source hands to SfM, MVS and the evaluation.

The folder holds ``000000.png, 000001.png, ...`` (8-bit grey or RGB) and ``timestamps.txt`` with
one line ``index t_seconds`` per frame, in the order the frames were taken (blank lines and lines
starting with ``#`` are ignored). The index names the PNG (``<index:06d>.png``); the time is on the
recording's clock, in seconds. Writers: the simulator's conventional camera and ground truth, the
ingest of a recording's APS frames, the reconstruction (:class:`FrameWriter`). Readers:
:func:`read_frames` and the helpers beside it, nothing else.

A folder is written under a temporary name and renamed when complete, so a reader sees a whole
folder or none.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evdense.formats.files import CompleteOrAbsent

TIMESTAMPS_NAME = "timestamps.txt"
"""The file listing a folder's frames."""


def frame_name(index: int) -> str:
    """The PNG name of frame ``index``: ``000042.png``."""
    return f"{int(index):06d}.png"


@dataclass(frozen=True)
class Frame:
    """One frame of a frames folder."""

    index: int
    """Frame index from timestamps.txt."""
    name: str
    """File name inside the frames folder (``000000.png``)."""
    t: float
    """Timestamp, seconds."""


def is_frames_dir(path: str | Path) -> bool:
    """Whether ``path`` is a frames folder (holds ``timestamps.txt``)."""
    return (Path(path) / TIMESTAMPS_NAME).is_file()


def resolve_frames_dir(path: str | Path) -> Path:
    """The folder holding the PNGs and ``timestamps.txt``: ``path`` itself or ``path/frames``."""
    path = Path(path)
    if is_frames_dir(path):
        return path
    if is_frames_dir(path / "frames"):
        return path / "frames"
    raise ValueError(
        f"{path}: no {TIMESTAMPS_NAME} here or in {path / 'frames'}; not a frames folder"
    )


def read_frames(frames_dir: str | Path, allow_empty: bool = False) -> list[Frame]:
    """The frames of a folder (``frames_dir`` or ``frames_dir/frames``), in file order.

    Raises ``ValueError`` naming the file and line when a line is malformed, when a listed PNG is
    missing, or (unless ``allow_empty``) when no frame is listed.
    """
    frames_dir = resolve_frames_dir(frames_dir)
    ts_path = frames_dir / TIMESTAMPS_NAME
    frames = []
    for lineno, line in enumerate(ts_path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        try:
            if len(parts) < 2:
                raise ValueError
            index, t = int(parts[0]), float(parts[1])
        except ValueError:
            raise ValueError(f"{ts_path}:{lineno}: expected 'index t_seconds', got {s!r}") from None
        name = frame_name(index)
        if not (frames_dir / name).is_file():
            raise ValueError(
                f"{ts_path}:{lineno}: frame {index} listed but {frames_dir / name} does not exist"
            )
        frames.append(Frame(index, name, t))
    if not frames and not allow_empty:
        raise ValueError(f"{ts_path}: no frames listed")
    return frames


def frame_paths_and_times(
    frames_dir: str | Path, allow_empty: bool = False
) -> tuple[list[Path], np.ndarray]:
    """PNG paths and times (seconds, float64 ``(N,)``) of a frames folder (see :func:`read_frames`)."""
    frames_dir = resolve_frames_dir(frames_dir)
    frames = read_frames(frames_dir, allow_empty)
    return [frames_dir / f.name for f in frames], np.array([f.t for f in frames], np.float64)


def format_timestamps(
    indices: Iterable[int], times: Iterable[float | int], unit: str = "s", decimals: int = 9
) -> str:
    """The text of ``timestamps.txt``. ``unit="s"``: float seconds written with ``decimals``
    decimals; ``unit="us"``: integer microseconds written exactly (``12.000345``)."""
    if unit == "s":
        return "".join(
            f"{int(i)} {float(t):.{decimals}f}\n" for i, t in zip(indices, times, strict=True)
        )
    if unit == "us":
        out = []
        for i, t in zip(indices, times, strict=True):
            t = int(t)
            sign, t = ("-", -t) if t < 0 else ("", t)
            out.append(f"{int(i)} {sign}{t // 1_000_000}.{t % 1_000_000:06d}\n")
        return "".join(out)
    raise ValueError(f"unit must be 's' or 'us', not {unit!r}")


def write_timestamps(
    frames_dir: str | Path,
    indices: Iterable[int],
    times: Iterable[float | int],
    unit: str = "s",
    decimals: int = 9,
) -> Path:
    """Write ``frames_dir/timestamps.txt`` (see :func:`format_timestamps`); returns its path."""
    path = Path(frames_dir) / TIMESTAMPS_NAME
    path.write_text(format_timestamps(indices, times, unit, decimals))
    return path


class FrameWriter(CompleteOrAbsent):
    """Write a frames folder (``000000.png``, ... and ``timestamps.txt``) atomically.

    Use as a context manager. Frames go to a temporary folder beside ``out_dir``, which is
    renamed to ``out_dir`` (replacing an older one) only when the block exits cleanly; on an
    exception the temporary folder is deleted, so ``out_dir`` is always complete or absent.
    """

    def __init__(self, out_dir: str | Path, compress_level: int = 1, decimals: int = 6) -> None:
        self.out_dir = Path(out_dir)
        self.compress_level = compress_level
        self.decimals = decimals
        self.out_dir.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = Path(
            tempfile.mkdtemp(
                prefix=f".{self.out_dir.name}.", suffix=".partial", dir=self.out_dir.parent
            )
        )
        self._times: list[float] = []

    def __len__(self) -> int:
        return len(self._times)

    def write(self, image: np.ndarray, t_s: float) -> Path:
        """Add one frame: ``image`` (H, W) float in [0, 1] or uint8, ``t_s`` its time in seconds."""
        from PIL import Image

        img = image if image.dtype == np.uint8 else to_uint8(image)
        path = self._tmp / frame_name(len(self._times))
        Image.fromarray(img).save(path, compress_level=self.compress_level)
        self._times.append(float(t_s))
        return path

    def close(self) -> Path:
        """Write ``timestamps.txt`` and move the folder to ``out_dir``."""
        write_timestamps(self._tmp, range(len(self._times)), self._times, decimals=self.decimals)
        if self.out_dir.exists():
            shutil.rmtree(self.out_dir)
        os.replace(self._tmp, self.out_dir)
        return self.out_dir

    def abort(self) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)


def to_uint8(image: np.ndarray) -> np.ndarray:
    """An image in [0, 1] (H, W) as 8-bit grey values (rounded, clipped)."""
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
