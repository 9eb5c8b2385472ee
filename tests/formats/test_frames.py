"""The frames folder, read and written through evdense.formats.frames only."""

from __future__ import annotations

import numpy as np
import pytest

from evdense.formats.frames import (
    FrameWriter,
    format_timestamps,
    frame_paths_and_times,
    read_frames,
    resolve_frames_dir,
    write_timestamps,
)


def _folder(path, n=3):
    with FrameWriter(path) as w:
        for i in range(n):
            w.write(np.full((6, 8), 40 * i, np.uint8), 0.05 * i)
    return path


def test_written_folder_reads_back(tmp_path):
    folder = _folder(tmp_path / "conv" / "frames")
    assert resolve_frames_dir(tmp_path / "conv") == folder  # the parent holding frames/ is accepted
    frames = read_frames(folder)
    assert [f.index for f in frames] == [0, 1, 2]
    assert [f.name for f in frames] == ["000000.png", "000001.png", "000002.png"]
    assert [f.t for f in frames] == pytest.approx([0.0, 0.05, 0.1])
    paths, times = frame_paths_and_times(tmp_path / "conv")
    assert paths == [folder / f.name for f in frames]
    assert times.dtype == np.float64 and times.tolist() == pytest.approx([0.0, 0.05, 0.1])
    assert not list(tmp_path.glob("conv/.*partial"))


def test_bad_folders_are_named(tmp_path):
    folder = _folder(tmp_path / "f")
    (folder / "000001.png").unlink()
    with pytest.raises(
        ValueError, match=r"timestamps\.txt:2: frame 1 listed but .*000001\.png does not exist"
    ):
        read_frames(folder)
    (folder / "timestamps.txt").write_text("# index t\n0 0.0\n2 oops\n")
    with pytest.raises(ValueError, match=r"timestamps\.txt:3: expected 'index t_seconds'"):
        read_frames(folder)
    (folder / "timestamps.txt").write_text("# nothing yet\n")
    with pytest.raises(ValueError, match="no frames listed"):
        read_frames(folder)
    assert frame_paths_and_times(folder, allow_empty=True)[1].shape == (0,)
    with pytest.raises(ValueError, match="not a frames folder"):
        resolve_frames_dir(tmp_path)


def test_timestamps_in_microseconds_are_exact(tmp_path):
    us = [0, 1, 999_999, 1_000_000, 1_234_567_890_123_457]
    text = format_timestamps(range(5), us, unit="us")
    assert text.splitlines() == [
        "0 0.000000", "1 0.000001", "2 0.999999", "3 1.000000", "4 1234567890.123457",
    ]  # fmt: skip
    assert format_timestamps([7], [0.1234567891]) == "7 0.123456789\n"
    for i in (0, 1):
        (tmp_path / f"{i:06d}.png").write_bytes(b"")  # only their presence is checked
    write_timestamps(tmp_path, [0, 1], [5, 1_700_000_000_000_001], unit="us")
    _, t = frame_paths_and_times(tmp_path)
    assert np.rint(t * 1e6).astype(np.int64).tolist() == [5, 1_700_000_000_000_001]
    with pytest.raises(ValueError, match="unit"):
        format_timestamps([0], [0], unit="ms")


def test_failed_writer_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with FrameWriter(tmp_path / "out") as w:
            w.write(np.zeros((4, 4)), 0.0)
            raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []
