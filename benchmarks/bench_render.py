"""Renders per second of each scene preset at 346x260 (DAVIS346), with supersample 1 and 2.

Usage: PYTHONPATH=src python benchmarks/bench_render.py [--frames 100] [--presets room desk facade]

Prints, per preset and supersampling factor: scene build time (s), ray casts alone per second
(open3d, incl. building the rays), full radiance renders per second (cast + shading), the shading
overhead per frame (ms), renders with depth + ids per second (the GT path), and CPU milliseconds
(all threads) per cast and per render, which depend less on other load on the machine.
Poses sweep the preset's trajectory, as the event simulator does.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from evdense.sim import PRESETS, Renderer, load_scene


def _rate(fn, poses: np.ndarray) -> tuple[float, float]:
    """Calls per second (wall clock) and CPU milliseconds per call (all threads)."""
    fn(poses[0])  # warm-up (numba compilation, buffers)
    t0, c0 = time.perf_counter(), time.process_time()
    for T in poses:
        fn(T)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return len(poses) / wall, 1000.0 * cpu / len(poses)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100, help="renders per measurement")
    ap.add_argument("--presets", nargs="*", default=sorted(PRESETS))
    args = ap.parse_args()
    print(f"cpus={os.cpu_count()} frames={args.frames} (346x260)")
    print(
        f"load average: {' '.join(f'{v:.1f}' for v in os.getloadavg())} (other processes slow the figures)"
    )
    head = (
        "preset",
        "ss",
        "build_s",
        "casts/s",
        "renders/s",
        "shade_ms",
        "gt_renders/s",
        "cpu_ms/cast",
        "cpu_ms/render",
    )
    print("{:8s} {:>2s} {:>7s} {:>8s} {:>9s} {:>8s} {:>12s} {:>11s} {:>13s}".format(*head))
    for name in args.presets:
        t0 = time.perf_counter()
        scene = load_scene({"scene": name})
        build = time.perf_counter() - t0
        poses = scene.trajectory.pose(np.linspace(0, scene.trajectory.duration, args.frames))
        for ss in (1, 2):
            r = Renderer(scene, supersample=ss)
            view = r._view(ss)
            casts, cpu_cast = _rate(lambda T, r=r, view=view: r._cast(view, T), poses)
            renders, cpu_render = _rate(r.radiance, poses)
            gt, _ = _rate(r.render, poses)
            shade_ms = 1000.0 * (1.0 / renders - 1.0 / casts)
            print(
                f"{name:8s} {ss:2d} {build:7.2f} {casts:8.1f} {renders:9.1f} {shade_ms:8.2f} {gt:12.1f}"
                f" {cpu_cast:11.2f} {cpu_render:13.2f}"
            )


if __name__ == "__main__":
    main()
