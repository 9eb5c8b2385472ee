"""Which format a recording is in (from its magic bytes first, its extension second), and opening it.

Format names (the dataset key ``format`` and ``evdense convert --format``): ``auto``, ``rpg_text``,
``e2vid_h5``, ``evdense``, ``aedat4``, ``rosbag`` (ROS 1 and ROS 2), ``evt2``, ``evt3``,
``prophesee_dat``, ``numpy``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from evdense.io.base import DEFAULT_CHUNK_EVENTS, Recording

FORMATS = (
    "rpg_text",
    "e2vid_h5",
    "evdense",
    "aedat4",
    "rosbag",
    "evt2",
    "evt3",
    "prophesee_dat",
    "numpy",
)

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def _head(path: Path, n: int = 512) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


def detect_format(path: str | Path) -> str:
    """Name of the format of ``path`` (a file, or a folder holding ``events.txt``).

    Raises ``ValueError`` naming the file when the format is not recognised or not supported.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such recording")
    if path.is_dir():
        if (path / "events.txt").exists():
            return "rpg_text"
        if (path / "metadata.yaml").exists():
            return "rosbag"
        raise ValueError(
            f"{path}: a folder with neither events.txt nor a ROS 2 bag's metadata.yaml; "
            "give the recording file itself"
        )
    head = _head(path)
    ext = path.suffix.lower()
    if head.startswith(b"#!AER-DAT4"):
        return "aedat4"
    if head.startswith(b"#!AER-DAT"):
        version = head[9:12].decode("ascii", errors="replace")
        raise ValueError(
            f"{path}: AEDAT {version} files are not supported (only AEDAT 4.0); convert with DV first"
        )
    if head.startswith(b"#ROSBAG V2.0") or head.startswith(b"\x89MCAP0\r\n"):
        return "rosbag"
    if head.startswith(b"SQLite format 3\x00") and ext == ".db3":
        return "rosbag"
    if head.startswith(b"#ROSBAG"):
        raise ValueError(f"{path}: unsupported ROS bag version {head[:13]!r}")
    if head.startswith(HDF5_MAGIC) or ext in (".h5", ".hdf5"):
        return _detect_h5(path)
    if head.startswith(b"\x93NUMPY") or ext in (".npy", ".npz"):
        return "numpy"
    if head.startswith(b"PK\x03\x04"):
        if ext == ".npz":
            return "numpy"
        import zipfile

        with zipfile.ZipFile(path) as z:
            names = [n.rsplit("/", 1)[-1] for n in z.namelist()]
        if "events.txt" in names:
            return "rpg_text"
        if any(n.endswith(".npy") for n in names):
            return "numpy"
        raise ValueError(f"{path}: a zip archive with neither events.txt nor .npy members")
    if head.startswith(b"%") or ext in (".raw", ".dat"):
        from evdense.io.prophesee import header_encoding, read_header

        lines, _ = read_header(path)
        enc = header_encoding(lines)
        if enc in ("evt2", "evt3"):
            return enc
        if enc is not None:
            raise ValueError(
                f"{path}: Prophesee encoding {enc} is not supported (only EVT 2.0 / 3.0 and DAT)"
            )
        if ext == ".dat" or any(
            s.lower().startswith(("data file containing", "version")) for s in lines
        ):
            return "prophesee_dat"
        if ext == ".raw":
            raise ValueError(
                f"{path}: a .raw file whose header does not name its encoding; give format evt2 or evt3"
            )
    if ext in (".txt", ".csv") or _looks_like_text_events(head):
        return "rpg_text"
    raise ValueError(
        f"{path}: unrecognised recording format (first bytes {head[:16]!r}); supported: {', '.join(FORMATS)}"
    )


def _looks_like_text_events(head: bytes) -> bool:
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        return False
    for line in text.splitlines()[:-1]:
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        return len(parts) == 4 and all(p.replace(".", "", 1).lstrip("-").isdigit() for p in parts)
    return False


def _detect_h5(path: Path) -> str:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") == "evdense-events":
                return "evdense"
            g = f.get("events")
            if g is not None and hasattr(g, "keys") and {"xs", "ys", "ts", "ps"} <= set(g.keys()):
                return "e2vid_h5"
            if g is not None and hasattr(g, "keys") and {"x", "y", "t", "p"} <= set(g.keys()):
                return "e2vid_h5"
            if "CD" in f:
                raise ValueError(
                    f"{path}: a Prophesee/Metavision HDF5 file (CD/events, ECF-compressed): not supported; "
                    "export it to EVT3 .raw or .dat"
                )
            keys = sorted(f.keys())
    except OSError as e:
        raise ValueError(f"{path}: not a readable HDF5 file ({e})") from e
    raise ValueError(f"{path}: HDF5 file without events/xs, ys, ts, ps (top-level keys: {keys})")


def open_recording(
    path: str | Path,
    fmt: str = "auto",
    chunk_events: int = DEFAULT_CHUNK_EVENTS,
    time_unit: str = "auto",
    **options: Any,
) -> Recording:
    """Open ``path`` as a :class:`~evdense.io.base.Recording` of format ``fmt`` ("auto" detects it).

    ``time_unit`` ("auto", "s", "ms", "us", "ns") applies to formats whose timestamps can be in
    several units (text, E2VID HDF5, NumPy). ``options`` go to the reader (e.g. ``topic`` for bags).
    """
    fmt = detect_format(path) if fmt in ("auto", None, "") else fmt
    if fmt == "rpg_text":
        from evdense.io.text import RpgTextRecording

        return RpgTextRecording(path, chunk_events, time_unit=time_unit)
    if fmt == "e2vid_h5":
        from evdense.io.h5formats import E2vidH5Recording

        return E2vidH5Recording(path, chunk_events, time_unit=time_unit)
    if fmt == "evdense":
        from evdense.io.h5formats import CanonicalH5Recording

        return CanonicalH5Recording(path, chunk_events)
    if fmt == "aedat4":
        from evdense.io.aedat4 import Aedat4Recording

        return Aedat4Recording(path, chunk_events)
    if fmt == "rosbag":
        from evdense.io.rosbag import RosbagRecording

        return RosbagRecording(path, chunk_events, **options)
    if fmt in ("evt2", "evt3"):
        from evdense.io.prophesee import RawRecording

        return RawRecording(path, chunk_events, encoding=fmt)
    if fmt == "prophesee_dat":
        from evdense.io.prophesee import DatRecording

        return DatRecording(path, chunk_events)
    if fmt == "numpy":
        from evdense.io.numpy_io import NumpyRecording

        return NumpyRecording(path, chunk_events, time_unit=time_unit)
    raise ValueError(f"{path}: unknown format {fmt!r}; choose one of auto, {', '.join(FORMATS)}")
