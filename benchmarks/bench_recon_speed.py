"""Reconstruction speed: milliseconds per frame of each network, per thread count.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_recon_speed.py
           [--size 346x260] [--frames 30] [--threads 2 1] [--nets firenet firenet_plus e2vid W.pt]

Times ``NetworkReconstructor.__call__`` (input normalisation, network with the recurrent state
carried over, clipping, copy back to numpy): the per-frame cost of the stage without file I/O.
Two variants run frame by frame in alternation, so that both see the same load on a shared
machine:

- ``optimised``: what the stage runs (channels-last layout; oneDNN convolutions with the
  activations and residual sums fused; gates of a ConvGRU in one convolution; fewer copies);
- ``plain``: the same network run as the research code does (NCHW layout, one op per layer);
- ``bf16``: the optimised variant with ``precision="bfloat16"`` (weights, activations and state
  in bfloat16: fast where the CPU has AVX-512 BF16 or AMX).

``--device cuda`` times the same on a GPU (each frame's result is copied back to the host, which
waits for the GPU).

Input: voxel grids (5 bins) of 25,000 random events per window. FireNet and FireNet+ use the
published weights when the anchors folder is present (random weights otherwise); E2VID
(lightweight) has random weights, which does not change its speed. A ``.pt`` path in ``--nets``
times that checkpoint (its own architecture, e.g. a ``train.arch: e2vid`` candidate). Printed
per network and thread count: median and best wall-clock milliseconds per frame of each
variant, CPU milliseconds per frame of the optimised one (all threads), and the median of the
per-frame speed-up, which the load of other processes changes far less than the times themselves.
On a machine shared with other jobs, set ``OMP_WAIT_POLICY=PASSIVE`` (the Snakemake rule does).
"""

from __future__ import annotations

import argparse
import copy
import os
import time
from pathlib import Path

import numpy as np
import torch

from evdense.events.voxel import voxel_grid
from evdense.recon import networks
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.inference import NetworkReconstructor
from evdense.recon.networks import ReconstructionNet, build_network

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


def network(name: str) -> tuple[ReconstructionNet, str]:
    if name.endswith((".pt", ".pth", ".tar")):  # a checkpoint of ours, e.g. a trained candidate
        loaded = load_checkpoint(name)
        return loaded.net, "file"
    path = ANCHORS / "weights" / PUBLISHED.get(name, "-")
    if path.is_file():
        return load_checkpoint(path).net, "published"
    torch.manual_seed(0)
    return build_network(name).eval(), "random"


def frame(rec: NetworkReconstructor, v: np.ndarray, fused: bool) -> float:
    networks.FUSED_INFERENCE = fused
    t0 = time.perf_counter()
    rec(v)
    return time.perf_counter() - t0


def compare(
    net: ReconstructionNet, grids: np.ndarray, warmup: int = 3, device: str = "cpu"
) -> dict[str, float]:
    opt = NetworkReconstructor(copy.deepcopy(net), device=device, channels_last=True)
    ref = NetworkReconstructor(copy.deepcopy(net), device=device, channels_last=False)
    bf = NetworkReconstructor(
        copy.deepcopy(net), device=device, channels_last=True, precision="bfloat16"
    )
    for v in grids[:warmup]:
        frame(opt, v, True)
        frame(ref, v, False)
        frame(bf, v, True)
    t_opt, t_ref, t_bf, cpu = [], [], [], 0.0
    for v in grids[warmup:]:
        c0 = time.process_time()
        t_opt.append(frame(opt, v, True))
        cpu += time.process_time() - c0
        t_ref.append(frame(ref, v, False))
        t_bf.append(frame(bf, v, True))
    networks.FUSED_INFERENCE = True
    a, b = np.array(t_opt), np.array(t_ref)
    return {
        "opt_median": 1e3 * np.median(a),
        "opt_best": 1e3 * a.min(),
        "opt_cpu": 1e3 * cpu / len(a),
        "ref_median": 1e3 * np.median(b),
        "ref_best": 1e3 * b.min(),
        "speedup": float(np.median(b / a)),
        "bf16_median": 1e3 * np.median(t_bf),
        "bf16_best": 1e3 * min(t_bf),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="346x260", help="W x H in pixels")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--threads", type=int, nargs="+", default=[2, 1])
    ap.add_argument("--nets", nargs="+", default=["firenet", "firenet_plus", "e2vid"])
    ap.add_argument("--device", default="cpu", help="cpu or cuda (times include the copy back)")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    grids = voxels(args.frames + 3, width, height)
    omp = os.environ.get("OMP_WAIT_POLICY", "default")
    where = torch.cuda.get_device_name() if args.device.startswith("cuda") else "CPU"
    print(
        f"torch {torch.__version__} on {where}, {os.cpu_count()} CPUs, OMP_WAIT_POLICY {omp}, "
        f"{width}x{height}, {args.frames} frames; times in ms per frame"
    )
    print(
        f"{'network':<14}{'weights':<11}{'threads':>7}{'opt median':>12}{'opt best':>10}"
        f"{'opt CPU':>9}{'plain median':>14}{'plain best':>12}{'speed-up':>10}"
        f"{'bf16 median':>13}{'bf16 best':>11}"
    )
    for name in args.nets:
        net, origin = network(name)
        name = getattr(net, "arch", name) if origin == "file" else name
        for threads in args.threads:
            torch.set_num_threads(threads)
            r = compare(net, grids, device=args.device)
            print(
                f"{name:<14}{origin:<11}{threads:>7}{r['opt_median']:>12.1f}{r['opt_best']:>10.1f}"
                f"{r['opt_cpu']:>9.1f}{r['ref_median']:>14.1f}{r['ref_best']:>12.1f}"
                f"{r['speedup']:>9.2f}x{r['bf16_median']:>13.1f}{r['bf16_best']:>11.1f}"
            )


if __name__ == "__main__":
    main()
