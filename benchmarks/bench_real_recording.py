"""A real recording through the whole workflow: the Event Camera Dataset's slider_depth, as a user
would give it (``datasets: {slider: {recording: <folder>}}``, nothing else).

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_real_recording.py
           [--anchors ../shared/anchors] [--work results/bench_real_recording] [--cores 2]
           [--set key=value ...]   (extra config, e.g. events.window.num_events=5000)

Runs ``snakemake --cores N`` on a config written into ``--work`` (its results go there too) and
prints, per image source: frames registered by SfM, the intrinsics it used, the ATE against the
recording's motion-capture poses (metres and % of the path), the fused cloud's points, the
textured mesh's faces, the event frames' SSIM against the nearest APS frame, and the wall time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def _set(conf: dict, key: str, value: str) -> None:
    *path, last = key.split(".")
    for k in path:
        conf = conf.setdefault(k, {})
    conf[last] = yaml.safe_load(value)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--work", default=str(ROOT / "results" / "bench_real_recording"))
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    rec = Path(args.anchors).resolve() / "data" / "ecd_slider_depth"
    if not rec.is_dir():
        sys.exit(f"{rec}: not found (give --anchors)")
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    conf: dict = {"datasets": {"slider": {"recording": str(rec)}}}
    for kv in args.set:
        key, _, value = kv.partition("=")
        _set(conf, key, value)
    (work / "config.yaml").write_text(yaml.safe_dump(conf))
    t0 = time.monotonic()
    cmd = [sys.executable, "-m", "snakemake", "--cores", str(args.cores), "-s",
           str(ROOT / "Snakefile"), "--directory", str(work), "--configfile",
           str(work / "config.yaml")]  # fmt: skip
    with open(work / "snakemake.log", "w") as log:
        rc = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
    wall = time.monotonic() - t0
    res = work / "results" / "slider"
    print(f"slider_depth as a recording: snakemake exit {rc}, wall {wall:.0f} s "
          f"({args.cores} cores; log {work / 'snakemake.log'})")  # fmt: skip
    print("| source | registered | intrinsics | ATE m | ATE % path | fused points | textured faces "
          "| SSIM vs nearest APS |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for sfm in sorted((res / "sfm").iterdir()) if (res / "sfm").is_dir() else []:
        src = sfm.name
        stats = (
            json.loads((sfm / "stats.json").read_text()) if (sfm / "stats.json").is_file() else {}
        )
        m_path = res / "eval" / src / "metrics.json"
        m = json.loads(m_path.read_text()) if m_path.is_file() else {}
        traj, img = m.get("trajectory", {}), m.get("images", {})
        mvs = res / "mvs" / src / "stats.json"
        points = json.loads(mvs.read_text()).get("fused_points") if mvs.is_file() else None
        obj = next((res / "mesh" / src).glob("*/textured/mesh.obj"), None)
        faces = sum(1 for ln in open(obj) if ln.startswith("f ")) if obj else None
        if stats.get("failed"):
            reg = f"failed: {stats.get('error')}"
        else:
            reg = f"{stats.get('num_registered')}/{stats.get('num_selected')}"
        ate = traj.get("ate_rmse")
        rel = traj.get("ate_rmse_relative")
        print(f"| {src} | {reg} | {stats.get('intrinsics_source')} | "
              f"{'-' if ate is None else f'{ate:.4f}'} | {'-' if rel is None else f'{100 * rel:.2f}'} | "
              f"{points} | {faces} | {img.get('ssim', '-') if img.get('num_frames') else '-'} |")  # fmt: skip
    sys.exit(rc)


if __name__ == "__main__":
    main()
