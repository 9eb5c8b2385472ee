"""The same scene as a synthetic dataset and as recordings in the formats users bring: does a
recording reach the same mesh? (issue 20)

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_recording_formats.py
           [--config config/test.yaml] [--work results/bench_recording_formats] [--cores 2]

1. Runs the workflow on ``--config`` (a synthetic scene; the tiny test scene by default).
2. Writes what its simulator made (events, the conventional camera's frames, the intrinsics, the
   GT poses) as recordings: an RPG folder (events.txt, images.txt + images/, calib.txt,
   groundtruth.txt), an AEDAT4 file (events + frames; calibration and poses given beside it with
   the dataset keys ``calibration`` and ``gt_trajectory``), a ROS 1 bag (dvs_msgs events,
   sensor_msgs images, CameraInfo, PoseStamped) and a ROS 2 bag (MCAP storage; event_camera_msgs
   EventPackets in libcaer_driver's ``libcaer`` encoding, with the same side data). Every one
   names the scene's GT mesh (``gt_mesh``).
3. Runs the workflow on those recordings with the same settings (SfM estimates the intrinsics as
   for the synthetic scene, ``sfm.calibration: null``, and runs single-threaded in both runs, so
   that identical input gives identical models).

Prints, per dataset and image source: frames registered, ATE (% of path) and the refined mesh's
F-score at the default threshold. Identical rows mean the readers hand the pipeline exactly what
the simulator made.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import yaml

from evdense.camera import load_camera
from evdense.events.container import EventFile
from evdense.poses import read_tum, write_tum
from evdense.testing.recordings import write_aedat4, write_rosbag1, write_rosbag2, write_rpg_text

ROOT = Path(__file__).resolve().parents[1]


def snakemake(work: Path, config: Path, cores: int) -> tuple[int, float]:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(ROOT / "Snakefile"), "--directory",
           str(work), "--configfile", str(config), "--cores", str(cores), "--set-threads",
           "run_sfm=1"]  # fmt: skip
    t0 = time.monotonic()
    with open(work / f"{config.stem}.log", "w") as log:
        rc = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
    return rc, time.monotonic() - t0


def frames_of(folder: Path) -> list[tuple[int, np.ndarray]]:
    rows = np.loadtxt(folder / "timestamps.txt", ndmin=2)
    return [(int(round(t * 1e6)), iio.imread(folder / f"{int(i):06d}.png")) for i, t in rows]


def write_recordings(res: Path, out: Path) -> dict[str, dict]:
    """The synthetic dataset ``res`` (results/<name>) as recordings under ``out``."""
    with EventFile(res / "events" / "events.h5") as f:
        ev, w, h = f.read(), f.width, f.height
    frames = frames_of(res / "conventional" / "frames")
    cam = load_camera(res / "gt" / "intrinsics.yaml")
    t_gt, T_gt = read_tum(res / "gt" / "trajectory.txt")
    gt = {"gt_mesh": str(res / "gt" / "mesh.ply")}
    rpg = out / "rpg"
    write_rpg_text(rpg, ev.t, ev.x, ev.y, ev.p, calib=cam)
    (rpg / "images").mkdir(exist_ok=True)
    lines = []
    for k, (t_us, img) in enumerate(frames):
        iio.imwrite(rpg / "images" / f"frame_{k:08d}.png", img)
        lines.append(f"{t_us / 1e6:.6f} images/frame_{k:08d}.png\n")
    (rpg / "images.txt").write_text("".join(lines))
    write_tum(rpg / "groundtruth.txt", t_gt, T_gt)
    (out / "poses.txt").write_text((rpg / "groundtruth.txt").read_text())
    write_aedat4(out / "rec.aedat4", ev.t, ev.x, ev.y, ev.p, w, h, frames=frames)
    write_rosbag1(out / "rec.bag", ev.t, ev.x, ev.y, ev.p, w, h, frames=frames, camera=cam,
                  poses=(t_gt, T_gt))  # fmt: skip
    write_rosbag2(out / "rec_ros2", ev.t, ev.x, ev.y, ev.p, w, h, frames=frames, camera=cam,
                  poses=(t_gt, T_gt))  # fmt: skip
    return {
        "as_rpg": {"recording": str(rpg), **gt},
        "as_aedat4": {
            "recording": str(out / "rec.aedat4"),
            **gt,
            "calibration": str(res / "gt" / "intrinsics.yaml"),
            "gt_trajectory": str(out / "poses.txt"),
        },  # fmt: skip
        "as_rosbag1": {"recording": str(out / "rec.bag"), **gt},
        "as_rosbag2": {"recording": str(out / "rec_ros2"), **gt},
    }


def rows(results: Path, dataset: str) -> list[tuple]:
    out = []
    for m in sorted((results / dataset / "eval").glob("*/metrics.json")):
        d = json.loads(m.read_text())
        sfm = d.get("sfm", {})
        g = d.get("geometry", {}).get("refined") or {}
        thr = d.get("config", {}).get("default_threshold")
        rel = g.get("relative_thresholds", [])
        fval = next((f for r, f in zip(rel, g.get("fscore", []), strict=False)
                     if thr is not None and abs(r - thr) < 1e-12), None)  # fmt: skip
        traj = d.get("trajectory", {})
        out.append((dataset, m.parent.name, sfm.get("num_registered"), sfm.get("num_selected"),
                    traj.get("ate_rmse_relative"), fval))  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "config" / "test.yaml"))
    ap.add_argument("--work", default=str(ROOT / "results" / "bench_recording_formats"))
    ap.add_argument("--cores", type=int, default=2)
    args = ap.parse_args()
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    base = yaml.safe_load(Path(args.config).read_text())
    base.setdefault("sfm", {})["calibration"] = None
    synth_cfg = work / "synthetic.yaml"
    synth_cfg.write_text(yaml.safe_dump(base))
    rc, wall_s = snakemake(work, synth_cfg, args.cores)
    if rc:
        sys.exit(f"synthetic run failed (log: {work / 'synthetic.log'})")
    (name,) = base["datasets"]
    recs = write_recordings(work / "results" / name, work / "recordings")
    rec_conf = {k: v for k, v in base.items() if k != "datasets"}
    rec_conf["datasets"] = recs
    rec_conf["summary_dir"] = "results/summary_recordings"
    rec_cfg = work / "recordings.yaml"
    rec_cfg.write_text(yaml.safe_dump(rec_conf))
    shutil.rmtree(work / "results" / "summary_recordings", ignore_errors=True)
    rc2, wall_r = snakemake(work, rec_cfg, args.cores)
    print(
        f"synthetic run {wall_s:.0f} s; recordings run {wall_r:.0f} s (exit {rc2}; logs in {work})"
    )
    print("| dataset | source | registered | ATE % path | refined F |")
    print("|---|---|---|---|---|")
    for ds in [name, *recs]:
        for r in rows(work / "results", ds):
            ate = "-" if r[4] is None else f"{100 * r[4]:.3f}"
            f = "-" if r[5] is None else f"{r[5]:.4f}"
            print(f"| {r[0]} | {r[1]} | {r[2]}/{r[3]} | {ate} | {f} |")
    sys.exit(rc2)


if __name__ == "__main__":
    main()
