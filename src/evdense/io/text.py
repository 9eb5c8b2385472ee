"""The RPG / Event Camera Dataset text layout, read in bounded memory.

A sequence folder holds ``events.txt`` (one event per line: ``t x y p``, ``t`` in seconds as a
decimal, ``p`` in {0, 1}) and, when present, ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 [k3]``),
``images.txt`` (``t images/frame_XXXXXXXX.png``) with the ``images/`` folder, and
``groundtruth.txt`` (``t px py pz qx qy qz qw``, camera-to-world, as TUM). The reader takes the
``events.txt`` path, its folder, or a ``.zip`` of the folder (as the dataset is distributed).

Timestamps are parsed from their decimal text (see :mod:`evdense.io._textparse`), so absolute
Unix times in seconds come out as exact microseconds; ``time_unit="us"`` or ``"ns"`` reads integer
timestamps instead ("auto": a decimal point in the first event line means seconds, none means
microseconds, logged).
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from evdense.camera import Camera
from evdense.io._textparse import ERROR_NAMES, OK, parse_block
from evdense.io.base import (
    DEFAULT_CHUNK_EVENTS,
    Frame,
    RawEvents,
    Recording,
    Trajectory,
    event_buffers,
)
from evdense.log import get_logger
from evdense.poses import read_tum

log = get_logger("io")

BYTES_PER_EVENT = 24  # a typical line; sets the text read per parse call from chunk_events
SIDE_FILES = ("calib.txt", "images.txt", "groundtruth.txt")


def _first_data_line(head: bytes) -> str | None:
    for line in head.decode("ascii", errors="replace").splitlines():
        s = line.strip()
        if s and not s.startswith(("#", "%")):
            return s
    return None


class RpgTextRecording(Recording):
    """``events.txt`` (+ side files) of the RPG / Event Camera Dataset layout."""

    format = "rpg_text"

    def __init__(
        self,
        path: str | Path,
        chunk_events: int = DEFAULT_CHUNK_EVENTS,
        time_unit: str = "auto",
    ) -> None:
        super().__init__(path, chunk_events)
        self._zip: zipfile.ZipFile | None = None
        self._folder: Path | None = None
        self._members: dict[str, str] = {}
        p = self.path
        if p.is_dir():
            self._folder = p
            self.events_name = "events.txt"
            if not (p / "events.txt").exists():
                raise ValueError(f"{p}: folder has no events.txt")
        elif p.suffix.lower() == ".zip":
            self._zip = zipfile.ZipFile(p)
            for name in self._zip.namelist():
                base = name.rsplit("/", 1)[-1]
                if base in ("events.txt", *SIDE_FILES):
                    self._members.setdefault(base, name)
            if "events.txt" not in self._members:
                raise ValueError(f"{p}: zip archive has no events.txt")
            self.events_name = self._members["events.txt"]
        else:
            self._folder = p.parent
            self.events_name = p.name
        with self._open_events() as f:
            head = f.read(4096)
        first = _first_data_line(head)
        if time_unit == "auto":
            if first is None:
                time_unit = "s"
            else:
                time_unit = "s" if "." in first.split()[0] else "us"
                if time_unit == "us":
                    log.info("%s: integer timestamps, read as microseconds", self.path)
        if time_unit not in ("s", "ms", "us", "ns"):
            raise ValueError(f"{self.path}: unknown time unit {time_unit!r}")
        self.time_unit = time_unit
        self.metadata["time_unit_in_file"] = time_unit

    def close(self) -> None:
        if self._zip is not None:
            self._zip.close()

    # --- files beside events.txt ----------------------------------------------------------
    def _open_events(self) -> IO[bytes]:
        if self._zip is not None:
            return self._zip.open(self.events_name)
        assert self._folder is not None
        return open(self._folder / self.events_name, "rb")

    def _side(self, name: str) -> bytes | None:
        if self._zip is not None:
            m = self._members.get(name)
            return self._zip.read(m) if m else None
        assert self._folder is not None
        f = self._folder / name
        return f.read_bytes() if f.exists() else None

    # --- events ---------------------------------------------------------------------------
    def _blocks(self, read_bytes: int) -> Iterator[tuple[np.ndarray, bool]]:
        """Yield ``(bytes of whole lines as uint8, is_last_block)``; zero-copy for plain files."""
        if self._zip is None:
            assert self._folder is not None
            f = self._folder / self.events_name
            size = f.stat().st_size
            if size == 0:
                return
            mm = np.memmap(f, dtype=np.uint8, mode="r")
            s = 0
            while s < size:
                e = min(s + read_bytes, size)
                while e < size:  # end the block after its last newline
                    nl = np.flatnonzero(mm[max(s, e - 65536) : e] == 10)
                    if len(nl):
                        e = max(s, e - 65536) + int(nl[-1]) + 1
                        break
                    e = min(e + read_bytes, size)  # a very long line: take more
                yield mm[s:e], e >= size
                s = e
            return
        rest = b""
        with self._open_events() as fh:
            while True:
                data = fh.read(read_bytes)
                buf = rest + data
                if not data:
                    if buf:
                        yield np.frombuffer(buf, dtype=np.uint8), True
                    return
                cut = buf.rfind(b"\n") + 1
                if cut == 0:
                    rest = buf
                    continue
                rest = buf[cut:]
                yield np.frombuffer(buf[:cut], dtype=np.uint8), False

    def iter_events(self) -> Iterator[RawEvents]:
        int_mult, frac = {"s": (10**6, 6), "ms": (10**3, 3), "us": (1, 0), "ns": (1, 0)}[
            self.time_unit
        ]
        name = self.path if self._zip is None else f"{self.path}:{self.events_name}"
        start = 0
        line0 = 0  # 0-based line number of the block's first line
        read_bytes = min(max(self.chunk_events * BYTES_PER_EVENT, 1 << 16), 1 << 26)
        for block, last in self._blocks(read_bytes):
            cap = len(block) // 8 + 1
            t, x, y, p = event_buffers(cap, np.int32, np.int8)
            skip_at = np.empty(cap + 1, np.int64)
            skip_count = np.empty(cap + 1, np.int64)
            ne, nl, ns, err, err_line = parse_block(
                block, t, x, y, p, skip_at, skip_count, int_mult, frac
            )
            if err != OK:
                lines = bytes(block).split(b"\n")
                text = lines[err_line].decode("ascii", errors="replace")
                lineno = line0 + err_line + 1
                if last and block[-1] != 10 and err_line == len(lines) - 1:
                    # the unterminated last line of the file does not parse: a truncated file
                    log.warning(
                        "%s: line %d is incomplete (%r): the file looks truncated; ignored that last line",
                        name,
                        lineno,
                        text[:80],
                    )
                else:
                    raise ValueError(f"{name}: line {lineno}: {ERROR_NAMES[err]}: {text[:80]!r}")
            if self.time_unit == "ns":
                t[:ne] = (t[:ne] + 500) // 1000
            if ne:
                yield RawEvents(
                    t[:ne],
                    x[:ne],
                    y[:ne],
                    p[:ne],
                    start=start,
                    locate=_line_locator(line0, skip_at[:ns].copy(), skip_count[:ns].copy()),
                )
            start += ne
            line0 += nl

    # --- side data ------------------------------------------------------------------------
    def camera(self, width: int, height: int) -> Camera | None:
        data = self._side("calib.txt")
        if data is None:
            return None
        try:
            vals = [float(v) for v in data.decode().split()]
        except ValueError as e:
            raise ValueError(f"{self.path}: calib.txt is not a list of numbers ({e})") from e
        if len(vals) < 4:
            raise ValueError(f"{self.path}: calib.txt: expected 'fx fy cx cy [k1 k2 p1 p2 k3]'")
        dist = tuple((vals[4:8] + [0.0] * 4)[:4])
        return Camera(width, height, vals[0], vals[1], vals[2], vals[3], dist)  # type: ignore[arg-type]

    def iter_frames(self) -> Iterator[Frame]:
        data = self._side("images.txt")
        if data is None:
            return
        for k, line in enumerate(data.decode().splitlines(), 1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = s.split()
            if len(parts) < 2:
                raise ValueError(f"{self.path}: images.txt line {k}: expected 't path', got {s!r}")
            t_us = _decimal_seconds_to_us(parts[0], self.path, k)
            rel = parts[1]
            if self._zip is not None:
                member = self._members["images.txt"].rsplit("/", 1)
                full = f"{member[0]}/{rel}" if len(member) == 2 else rel
                try:
                    raw = self._zip.read(full)
                except KeyError as e:
                    raise ValueError(
                        f"{self.path}: images.txt line {k}: {rel} not in the archive"
                    ) from e
                import imageio.v3 as iio

                yield Frame(t_us, image=iio.imread(io.BytesIO(raw)))
            else:
                assert self._folder is not None
                src = self._folder / rel
                if Path(rel).is_absolute() or not src.resolve().is_relative_to(
                    self._folder.resolve()
                ):
                    raise ValueError(
                        f"{self._folder / 'images.txt'}: line {k}: {rel!r} is outside the "
                        "recording's folder (image paths must be relative and stay inside it)"
                    )
                if not src.exists():
                    raise ValueError(
                        f"{self._folder / 'images.txt'}: line {k}: {src} does not exist"
                    )
                yield Frame(t_us, source=src)

    def trajectory(self) -> Trajectory | None:
        if self._zip is not None:
            data = self._side("groundtruth.txt")
            if data is None:
                return None
            import tempfile

            with tempfile.TemporaryDirectory() as d:
                f = Path(d) / "groundtruth.txt"
                f.write_bytes(data)
                t, T = read_tum(f)
            return Trajectory(t, T, source=f"{self.path}:groundtruth.txt")
        assert self._folder is not None
        f = self._folder / "groundtruth.txt"
        if not f.exists():
            return None
        t, T = read_tum(f)
        return Trajectory(t, T, source=str(f))


def _line_locator(line0: int, skip_at: np.ndarray, skip_count: np.ndarray):
    """Map a batch event index to its 1-based line number, given the runs of skipped lines."""
    cum = np.cumsum(skip_count)

    def locate(i: int) -> str:
        # skipped lines recorded at event count c come before event c
        r = int(np.searchsorted(skip_at, i, side="right"))
        before = int(cum[r - 1]) if r else 0
        return f"line {line0 + i + before + 1}"

    return locate


def _decimal_seconds_to_us(s: str, path: Path, line: int) -> int:
    """Exact decimal seconds text to integer microseconds (rounded half up)."""
    try:
        if "e" in s.lower():
            return int(round(float(s) * 1e6))
        ip, _, fp = s.partition(".")
        fp = (fp + "0000000")[:7]
        us = int(ip or "0") * 1_000_000 + int(fp[:6])
        return us + (1 if int(fp[6]) >= 5 else 0)
    except ValueError as e:
        raise ValueError(f"{path}: line {line}: cannot read timestamp {s!r}") from e
