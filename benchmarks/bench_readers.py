"""Reader throughput: events per second for each input format and for the canonical HDF5 file.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_readers.py [--events 5000000] [--others 2000000]

Generates seeded random streams (346x260, ~1 us between events) in a temporary folder, then
times, best of ``--repeats`` runs, with the files in the page cache:
- parsing the RPG text layout (``events.txt``) and a full ``ingest`` of it (parse + validate + write);
- iterating over the canonical event file (``EventFile.iter_chunks``) as written with LZF
  compression (the container's default) and without compression (``ingest.compression: none``);
- decoding each other format (DAT, EVT2, EVT3, AEDAT4 LZ4, ROS1 bag, NPZ, E2VID HDF5).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from evdense.events.container import EventFile, Events, EventWriter
from evdense.io import IngestConfig, ingest_recording, open_recording
from evdense.testing.recordings import (
    write_aedat4,
    write_dat,
    write_e2vid_h5,
    write_evt2,
    write_evt3,
    write_npz,
    write_rosbag1,
    write_rpg_text,
)

W, H = 346, 260


def stream(n: int, seed: int = 0) -> Events:
    rng = np.random.default_rng(seed)
    t = 1_500_000_000_000_000 + np.cumsum(rng.integers(0, 3, n))
    return Events(t, rng.integers(0, W, n), rng.integers(0, H, n), rng.choice([-1, 1], n))


def best_of(fn: Callable[[], int], repeats: int) -> tuple[float, int]:
    best, n = float("inf"), 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        n = fn()
        best = min(best, time.perf_counter() - t0)
    return best, n


def count_events(path: Path, fmt: str = "auto") -> int:
    with open_recording(path, fmt) as rec:
        return sum(len(b) for b in rec.iter_events())


def report(name: str, seconds: float, n: int) -> None:
    print(
        f"{name:<44s} {n / seconds / 1e6:8.1f} M events/s   ({n:,} events in {seconds:.2f} s)",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--events", type=int, default=5_000_000, help="events for the text and canonical benchmarks"
    )
    ap.add_argument("--others", type=int, default=2_000_000, help="events for the other formats")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    ev = stream(args.events)
    small = ev[: args.others]
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        # warm-up: compile the numba parsers (cached on disk after the first run)
        write_rpg_text(d / "warm", small.t[:1000], small.x[:1000], small.y[:1000], small.p[:1000])
        count_events(d / "warm" / "events.txt")

        txt = write_rpg_text(d / "seq", ev.t, ev.x, ev.y, ev.p)
        print(f"events.txt: {txt.stat().st_size / 1e6:.0f} MB, {args.events:,} events")
        report("RPG text: parse", *best_of(lambda: count_events(txt), args.repeats))
        for comp in ("lzf", "none"):
            cfg = IngestConfig(compression=comp)
            report(
                f"RPG text: ingest (parse+validate+write, {comp})",
                *best_of(
                    lambda cfg=cfg: (
                        ingest_recording(
                            txt, d / "ing.h5", width=W, height=H, config=cfg
                        ).num_events
                    ),
                    1,
                ),
            )

        for comp in ("lzf", None):
            path = d / f"canonical_{comp}.h5"
            with EventWriter(path, W, H, compression=comp) as w:
                for s in range(0, len(ev), 1 << 20):
                    w.append(ev[s : s + (1 << 20)])

            def read(path: Path = path) -> int:
                with EventFile(path) as f:
                    return sum(len(b) for b in f.iter_chunks())

            size = path.stat().st_size / len(ev)
            report(
                f"canonical HDF5 iter_chunks ({comp or 'none'}, {size:.1f} B/event)",
                *best_of(read, args.repeats),
            )

        s = small
        files = {
            "Prophesee DAT": write_dat(d / "e.dat", s.t - s.t[0], s.x, s.y, s.p, W, H),
            "Prophesee EVT2 .raw": write_evt2(d / "e2.raw", s.t - s.t[0], s.x, s.y, s.p, W, H),
            "AEDAT4 (LZ4)": write_aedat4(
                d / "e.aedat4", s.t, s.x, s.y, s.p, W, H, packet_events=10_000
            ),
            "ROS1 bag (dvs_msgs)": write_rosbag1(
                d / "e.bag", s.t, s.x, s.y, s.p, W, H, events_per_message=10_000
            ),
            "NumPy .npz": write_npz(d / "e.npz", s.t, s.x, s.y, s.p, W, H),
            "E2VID HDF5 (ts float s)": write_e2vid_h5(d / "e.h5", s.t, s.x, s.y, s.p, W, H),
        }
        m = min(len(s), 500_000)  # the EVT3 writer is a Python loop
        files["Prophesee EVT3 .raw"] = write_evt3(
            d / "e3.raw", s.t[:m] - s.t[0], s.x[:m], s.y[:m], s.p[:m], W, H
        )
        for name, path in files.items():
            report(f"{name}: decode", *best_of(lambda path=path: count_events(path), args.repeats))


if __name__ == "__main__":
    main()
