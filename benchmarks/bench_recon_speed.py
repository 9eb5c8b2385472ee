"""Reconstruction speed: milliseconds per frame of each network, per thread count and memory layout.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_recon_speed.py
           [--size 346x260] [--frames 20] [--threads 1 2] [--nets firenet firenet_plus e2vid]

Times ``NetworkReconstructor.__call__`` (input normalisation, network with the recurrent state
carried over, clipping, copy back to numpy): the per-frame cost of the stage without file I/O.
Input: voxel grids (5 bins) of 25,000 random events per window. FireNet and FireNet+ use the
published weights when the anchors folder is present (random weights otherwise); E2VID
(lightweight) has random weights, which does not change its speed. Prints, per configuration,
the median and the best wall-clock milliseconds per frame over ``--frames`` frames (after 3
warm-up frames) and the CPU milliseconds per frame (all threads), which depends less on other
load on the machine.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

from evdense.events.voxel import voxel_grid
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.inference import NetworkReconstructor
from evdense.recon.networks import build_network

ANCHORS = Path(
    os.environ.get("EVDENSE_ANCHORS", Path(__file__).resolve().parents[2] / "shared" / "anchors")
)
PUBLISHED = {"firenet": "firenet_1000.pth.tar", "firenet_plus": "firenet_plus.pth"}


def voxels(n: int, width: int, height: int, events: int = 25_000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        t = np.sort(rng.integers(0, 30_000, events))
        x, y = rng.integers(0, width, events), rng.integers(0, height, events)
        p = rng.choice(np.array([-1, 1], np.int8), events)
        out.append(voxel_grid(t, x, y, p, 5, height, width))
    return np.stack(out)


def network(name: str) -> tuple[torch.nn.Module, str]:
    path = ANCHORS / "weights" / PUBLISHED.get(name, "-")
    if path.is_file():
        return load_checkpoint(path).net, "published"
    torch.manual_seed(0)
    return build_network(name).eval(), "random"


def time_frames(
    rec: NetworkReconstructor, grids: np.ndarray, warmup: int = 3
) -> tuple[float, float, float]:
    for v in grids[:warmup]:
        rec(v)
    wall = []
    c0 = time.process_time()
    for v in grids[warmup:]:
        t0 = time.perf_counter()
        rec(v)
        wall.append(time.perf_counter() - t0)
    cpu = (time.process_time() - c0) / len(wall)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.min(wall)), 1e3 * cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="346x260", help="W x H in pixels")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--nets", nargs="+", default=["firenet", "firenet_plus", "e2vid"])
    ap.add_argument("--layouts", nargs="+", default=["channels_last", "contiguous"])
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    grids = voxels(args.frames + 3, width, height)
    print(
        f"torch {torch.__version__}, {os.cpu_count()} CPUs, {width}x{height}, {args.frames} frames"
    )
    print(
        f"{'network':<14}{'weights':<11}{'layout':<15}{'threads':>7}{'median ms':>11}{'best ms':>9}{'CPU ms':>8}"
    )
    for name in args.nets:
        net, origin = network(name)
        for layout in args.layouts:
            for threads in args.threads:
                torch.set_num_threads(threads)
                rec = NetworkReconstructor(net, channels_last=layout == "channels_last")
                med, best, cpu = time_frames(rec, grids)
                print(
                    f"{name:<14}{origin:<11}{layout:<15}{threads:>7}{med:>11.1f}{best:>9.1f}{cpu:>8.1f}"
                )


if __name__ == "__main__":
    main()
