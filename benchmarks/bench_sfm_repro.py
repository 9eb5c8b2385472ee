"""Is SfM reproducible? The same frames through the sfm stage several times, per thread count.

Usage:
    PYTHONPATH=src python benchmarks/bench_sfm_repro.py FRAMES_DIR [--threads 1 2] [--repeats 2]
        [--work DIR]

Runs ``run_sfm`` with the default ``sfm`` config (seeds set) ``--repeats`` times for each thread
count, and prints per run: frames registered, 3D points, focal length, and the largest camera-centre
difference to the first run of the same thread count (model units, and as a % of that run's path
length), plus whether the two runs' camera centres are identical to the last digit. A difference means
the runs downstream of SfM (MVS, mesh, metrics) cannot be compared digit for digit either.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from evdense.log import setup_logging
from evdense.sfm import read_sfm_trajectory, run_sfm


def centres(model: Path) -> dict[float, np.ndarray]:
    """Camera centre per timestamp of a written model."""
    times, poses = read_sfm_trajectory(model)
    return {float(t): pose[:3, 3].copy() for t, pose in zip(times, poses, strict=True)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("frames", type=Path, help="a frames folder (PNGs + timestamps.txt)")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--work", type=Path, default=None, help="keep the models here")
    a = ap.parse_args()
    setup_logging(None)
    work = a.work or Path(tempfile.mkdtemp(prefix="evdense_sfm_repro_"))
    print(f"frames {a.frames}; models under {work}")
    print("threads run registered points3D focal_px wall_s max_centre_diff diff_%_path identical")
    for threads in a.threads:
        first: dict[float, np.ndarray] | None = None
        for k in range(a.repeats):
            out = work / f"t{threads}_r{k}"
            t0 = time.perf_counter()
            stats = run_sfm(a.frames, out, {}, num_threads=threads)
            wall = time.perf_counter() - t0
            c = centres(out)
            if first is None:
                first = c
                diff, pct, same = 0.0, 0.0, "-"
            else:
                common = sorted(set(c) & set(first))
                d = np.array([np.linalg.norm(c[t] - first[t]) for t in common])
                path = np.sum(np.linalg.norm(np.diff([first[t] for t in common], axis=0), axis=1))
                diff = float(d.max()) if len(d) else float("nan")
                pct = 100.0 * diff / path if path > 0 else float("nan")
                same = "yes" if set(c) == set(first) and diff == 0.0 else "no"
            print(
                f"{threads:7d} {k:3d} {stats['num_registered']:10d} {stats['num_points3D']:8d} "
                f"{stats['camera']['focal_length']:8.3f} {wall:6.1f} {diff:15.3g} {pct:11.3g} {same}",
                flush=True,
            )


if __name__ == "__main__":
    main()
