"""Event frames of the high-dynamic-range scenes against GT intensity: any weights, side by side.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_recon_hdr.py
           [--ours NAME=WEIGHTS.pt ...] [--anchors ../shared/anchors] [--cores 2]
           [--speed 1] [--dynamic-range 100000]

Issue 18's HDR figure (event-frame image SSIM >= 0.55 on each scene) is measured by the workflow
on ``config/claim.yaml``'s HDR datasets (``room``, ``desk`` and ``facade`` at speed 1 and a
dynamic range of 100,000), but only for the shipped weights and as part of a whole run. This
script asks Snakemake for the frames alone (simulated scene, events, windows, voxels, frames), for
the shipped weights (``ours``), published FireNet and every ``--ours NAME=WEIGHTS.pt`` given, with
the pipeline's defaults otherwise (25,000-event windows), and scores them as the evaluation stage
does (:func:`evdense.evaluate.images.evaluate_images`, up to 60 frames evenly spaced), against GT
intensity rendered at each frame's time: SSIM against the log-mapped GT after matching the frame's
histogram to it (the report's figure), and SSIM with both rescaled by their own 1st-99th
percentiles (GT in linear radiance). The datasets
are those of a claim or experiment run (``results/<scene>_s1_dr100000/``): made once, reused.
Simulating the three scenes takes several minutes on two cores; each network's frames under one.

``--speed`` and ``--dynamic-range`` score another corner of ``config/experiment.yaml``'s sweep
the same way (``results/<scene>_s<speed>_dr<dr>/``, made as that sweep makes it): ``--speed 4
--dynamic-range 1`` gives the three scenes as the default run sees ``room``, a 346 x 260 camera
in fast motion at an ordinary dynamic range, the setting of issue 18's independent simulator.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from evdense.evaluate.config import EvalConfig
from evdense.evaluate.images import evaluate_images

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("room", "desk", "facade")
WINDOWS = "n25000_b5"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ours", nargs="*", default=[], help="NAME=WEIGHTS.pt (our format)")
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--speed", type=int, default=1, help="a speed of the sweep")
    ap.add_argument(
        "--dynamic-range", type=int, default=100000, help="a dynamic range of the sweep"
    )
    args = ap.parse_args()
    checkpoints = {}
    for item in args.ours:
        name, sep, path = item.partition("=")
        if not sep or not name.isidentifier() or not Path(path).is_file():
            raise SystemExit(f"--ours {item!r}: give NAME=WEIGHTS.pt with an existing file")
        if name in ("ours", "firenet"):  # the shipped weights and published FireNet's rows
            raise SystemExit(f"--ours {item!r}: the name {name!r} is taken; choose another")
        checkpoints[name] = str(Path(path).resolve())
    firenet = Path(args.anchors) / "weights" / "firenet_1000.pth.tar"
    if firenet.is_file():
        checkpoints["firenet"] = str(firenet.resolve())
    methods = ["ours", *checkpoints]
    overlay = ROOT / "results" / "benchmarks" / "hdr_frames.yaml"
    overlay.parent.mkdir(parents=True, exist_ok=True)
    sweep = {"speeds": [args.speed], "dynamic_ranges": [args.dynamic_range]}
    overlay.write_text(
        yaml.safe_dump({"reconstruct": {"checkpoints": checkpoints}, "sweep": sweep})
    )
    datasets = [f"{s}_s{args.speed}_dr{args.dynamic_range}" for s in SCENES]
    targets = [f"results/{d}/gt" for d in datasets]
    targets += [f"results/{d}/frames/{m}_{WINDOWS}" for d in datasets for m in methods]
    cmd = [sys.executable, "-m", "snakemake", "--cores", str(args.cores), "--configfile",
           "config/claim.yaml", str(overlay), "--", *targets]  # fmt: skip
    subprocess.run(cmd, cwd=ROOT, check=True)

    modes = {"histogram": "SSIM vs log GT (histogram matched)", "percentile": "SSIM vs linear GT"}
    for mode, title in modes.items():
        conf = EvalConfig(image_mode=mode)
        print(f"\n{title}; speed {args.speed}, dynamic range {args.dynamic_range}, {WINDOWS}, "
              f"up to {conf.max_image_frames} frames per scene\n")  # fmt: skip
        print("| weights | " + " | ".join(SCENES) + " | lowest |")
        print("| --- " * (len(SCENES) + 2) + "|")
        for m in methods:
            row = [
                evaluate_images(ROOT / "results" / d / "frames" / f"{m}_{WINDOWS}",
                                ROOT / "results" / d / "gt", conf)["ssim"]
                for d in datasets
            ]  # fmt: skip
            cells = " | ".join(f"{v:.3f}" for v in row)
            print(f"| {m} | {cells} | {np.min(row):.3f} |")
    if args.dynamic_range == 100000:
        print("\ntarget (issue 18): SSIM vs log GT >= 0.55 on each scene")


if __name__ == "__main__":
    main()
