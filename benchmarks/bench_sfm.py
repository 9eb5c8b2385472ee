"""SfM quality per image source on the default fast-motion scene, and the time of 60 frames.

Usage:
    PYTHONPATH=src python benchmarks/bench_sfm.py [--dataset-dir results/room_fast]
        [--frames NAME=DIR ...] [--work DIR] [--threads 2] [--skip-timing]

Quality: for each image source (GT frames, conventional frames, and any ``--frames NAME=DIR``,
e.g. reconstructed event frames ``firenet=results/room_fast/frames/firenet_n25000_b5``), SfM with
the default ``sfm`` config, then: % of frames registered, mean reprojection error (px, target < 1),
estimated focal length and its error against GT, camera-centre RMSE after Sim(3) alignment to the
GT trajectory as a % of the trajectory length (target < 1 %), wall time.
Without ``--dataset-dir`` the default dataset (``room`` at speed 4, 346x260, 20 frames) is simulated
into the work folder first.

Timing: 60 frames at 346x260 (``room`` at speed 4/3, GT frames, ``select: count``, 60) through
the whole stage; prints wall and CPU seconds (all threads) per run and the load average, since
other processes on the machine slow the wall-clock figure.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from evdense.camera import load_camera
from evdense.config import validate_config
from evdense.evaluate.align import align_trajectory_to_gt
from evdense.log import setup_logging
from evdense.poses import read_tum
from evdense.sfm import SfmError, read_sfm_trajectory, run_sfm


def simulate(out: Path, speed: float, conventional: bool) -> Path:
    """Simulate the `room` preset at ``speed`` into ``out`` (gt/, conventional/) unless present."""
    from evdense.sim.groundtruth import write_groundtruth
    from evdense.sim.simulate import simulate_conventional

    cfg = validate_config({"datasets": {"d": {"scene": "room", "speed": speed}}})
    if not (out / "gt").is_dir():
        write_groundtruth(cfg["datasets"]["d"], cfg["simulator"], out / "gt")
    if conventional and not (out / "conventional").is_dir():
        simulate_conventional(cfg["datasets"]["d"], cfg["simulator"], out / "conventional")
    return out


def measure(frames: Path, gt_dir: Path, out: Path, conf: dict, threads: int) -> dict:
    """Run SfM once and return the figures (or the failure)."""
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        st = run_sfm(frames, out, conf, num_threads=threads)
    except SfmError as e:
        return {"error": str(e).split(". ")[0], "wall_s": time.perf_counter() - t0}
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    t_est, T_est = read_sfm_trajectory(out)
    t_gt, T_gt = read_tum(gt_dir / "trajectory.txt")
    ce = align_trajectory_to_gt(t_est, T_est, t_gt, T_gt)
    f_gt = load_camera(gt_dir / "intrinsics.yaml").fx
    return {
        "frames": st["num_selected"],
        "registered_pct": 100.0 * st["registered_fraction"],
        "points": st["num_points3D"],
        "track_len": st["mean_track_length"],
        "reproj_px": st["mean_reprojection_error_px"],
        "f_px": st["camera"]["focal_length"],
        "f_err_pct": 100.0 * (st["camera"]["focal_length"] / f_gt - 1),
        "centre_rmse_mm": 1000.0 * ce.rmse,
        "centre_rmse_pct": 100.0 * ce.rmse_rel,
        "path_m": ce.trajectory_length,
        "wall_s": wall,
        "cpu_s": cpu,
        "steps": {k: round(v, 2) for k, v in st["time_s"].items()},
    }


def print_row(name: str, r: dict) -> None:
    if "error" in r:
        print(f"{name:14s} FAILED: {r['error']} ({r['wall_s']:.1f} s)")
        return
    print(
        f"{name:14s} {r['frames']:6d} {r['registered_pct']:6.1f} {r['points']:7d} {r['track_len']:6.2f} "
        f"{r['reproj_px']:8.3f} {r['f_px']:7.2f} {r['f_err_pct']:+7.2f} {r['centre_rmse_mm']:8.2f} "
        f"{r['centre_rmse_pct']:8.3f} {r['path_m']:6.2f} {r['wall_s']:7.1f} {r['cpu_s']:7.1f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--dataset-dir", type=Path, help="results/{dataset} holding gt/ (and conventional/)"
    )
    ap.add_argument(
        "--frames", nargs="*", default=[], help="extra sources NAME=DIR (frames folders)"
    )
    ap.add_argument(
        "--work", type=Path, help="folder for simulated data and SfM outputs (default: temporary)"
    )
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--config", default="{}", help="sfm config section as JSON (default: the defaults)"
    )
    ap.add_argument("--skip-timing", action="store_true", help="skip the 60-frame timing run")
    args = ap.parse_args()
    setup_logging()
    conf = json.loads(args.config)
    tmp = None
    if args.work is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_sfm_")
        args.work = Path(tmp.name)
    args.work.mkdir(parents=True, exist_ok=True)

    data = args.dataset_dir or simulate(args.work / "room_fast", 4.0, conventional=True)
    sources = {"gt": data / "gt" / "frames"}
    if (data / "conventional").is_dir():
        sources["conventional"] = data / "conventional"
    for spec in args.frames:
        name, _, path = spec.partition("=")
        sources[name] = Path(path)
    results = {}
    for name, frames in sources.items():
        results[name] = measure(frames, data / "gt", args.work / "sfm" / name, conf, args.threads)

    timing = None
    if not args.skip_timing:
        d60 = simulate(args.work / "room_60", 4.0 / 3.0, conventional=False)
        timing = measure(
            d60 / "gt" / "frames",
            d60 / "gt",
            args.work / "sfm" / "timing60",
            {**conf, "select": "count"},
            args.threads,
        )

    print()
    print(f"SfM benchmark: {data} (346x260), threads={args.threads}, cpus={os.cpu_count()}")
    print(
        f"load average: {' '.join(f'{v:.1f}' for v in os.getloadavg())} (other processes slow wall times)"
    )
    print(
        f"{'source':14s} {'frames':>6s} {'reg%':>6s} {'points':>7s} {'track':>6s} {'reproj':>8s} {'f_px':>7s} "
        f"{'f_err%':>7s} {'ctr_mm':>8s} {'ctr_%len':>8s} {'path_m':>6s} {'wall_s':>7s} {'cpu_s':>7s}"
    )
    for name, r in results.items():
        print_row(name, r)
    if timing is not None:
        print()
        print("60 frames at 346x260, whole stage (target <= 60 s):")
        print_row("gt_60", timing)
        if "steps" in timing:
            print(f"  per step (s): {timing['steps']}")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
