"""Peak memory of `evdense convert` on a large recording (issue 21: 100 M events under 1.5 GB).

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_convert_memory.py
           [--events 100000000] [--rate 10e6] [--work results/bench_convert]

Writes a Prophesee EVT 2.0 file of ``--events`` random events on a 640 x 480 sensor at ``--rate``
events per second (in chunks of 10 M, so this script itself stays small), then runs
``evdense convert`` on it in a child process and prints the child's wall time, its peak RSS
(``ru_maxrss`` of the children) and the size of both files. The input and output are deleted at the
end unless ``--keep``.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from evdense.testing.recordings import write_evt2

ROOT = Path(__file__).resolve().parents[1]
W, H = 640, 480


def write_big_evt2(path: Path, n: int, rate: float, chunk: int = 10_000_000) -> None:
    """EVT2 file of ``n`` random events, written chunk by chunk (header once)."""
    rng = np.random.default_rng(0)
    t0 = 0
    with open(path, "wb") as out:
        for k, start in enumerate(range(0, n, chunk)):
            m = min(chunk, n - start)
            dt = rng.exponential(1e6 / rate, m)
            t = t0 + np.floor(np.cumsum(dt)).astype(np.int64)
            t0 = int(t[-1])
            x = rng.integers(0, W, m)
            y = rng.integers(0, H, m)
            p = rng.integers(0, 2, m)
            part = path.with_name(path.name + ".chunk")
            write_evt2(part, t, x, y, p, W, H)
            data = part.read_bytes()
            part.unlink()
            if k > 0:  # drop the header of every chunk after the first
                end = 0
                while data[end : end + 1] == b"%":
                    end = data.index(b"\n", end) + 1
                data = data[end:]
            out.write(data)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=100_000_000)
    ap.add_argument("--rate", type=float, default=10e6, help="events per second")
    ap.add_argument("--work", default=str(ROOT / "results" / "bench_convert"))
    ap.add_argument("--keep", action="store_true")
    args = ap.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    raw, h5 = work / "big.raw", work / "big.h5"
    t0 = time.monotonic()
    write_big_evt2(raw, args.events, args.rate)
    print(f"wrote {args.events:,} events ({raw.stat().st_size / 1e6:.0f} MB EVT2) in "
          f"{time.monotonic() - t0:.0f} s")  # fmt: skip
    cli = [sys.executable, "-m", "evdense.cli", "convert", str(raw), str(h5)]
    t0 = time.monotonic()
    res = subprocess.run(cli, capture_output=True, text=True)
    wall = time.monotonic() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    if res.returncode != 0:
        raise SystemExit(f"evdense convert failed ({res.returncode}):\n{res.stderr[-2000:]}")
    print(f"evdense convert: {wall:.1f} s wall, peak RSS {peak_mb:.0f} MB, "
          f"{args.events / wall / 1e6:.1f} M events/s, output {h5.stat().st_size / 1e6:.0f} MB")  # fmt: skip
    if not args.keep:
        shutil.rmtree(work)


if __name__ == "__main__":
    main()
