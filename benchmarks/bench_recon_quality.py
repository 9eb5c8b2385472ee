"""Reconstruction quality on held-out simulated sequences: our weights vs published ones vs baselines.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_recon_quality.py
           [--data results/training/heldout_s0.h5] [--ours resources/weights/evfirenet.pt [more.pt ...]]
           [--anchors /work/shared/anchors] [--threads 2]

The held-out split (24 sequences of 32 windows of 0.3 events/pixel at 128 x 96: checkerboards,
held-out skimage pictures, cylinders and floors, fast / shaking / HDR motion; see
``evdense.training.data``) is read from ``--data``, a training-set file or a held-out-only file;
when the file is missing it is simulated with the default ``train`` recipe and seed (the same
sequences as the held-out split of the shipped model's training set) and cached there.

Methods: our shipped weights, published FireNet and FireNet+ (from the anchors folder, skipped when
absent), the high-pass filter and direct integration (given the true contrast thresholds). Metric
(``evdense.training.heldout``): per-frame robust min/max (1st/99th percentiles) of prediction and
GT alike, then MSE and SSIM, averaged over all frames after the first 5 of each sequence; ``ssim``
is against log-radiance GT (our GT frames' tone mapping), ``ssim_linear`` against linear radiance.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from evdense.log import setup_logging
from evdense.training.data import generate_dataset
from evdense.training.heldout import EvalConfig, evaluate_methods, format_table
from evdense.training.train import TrainConfig

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT / "results/training/heldout_s0.h5"))
    ap.add_argument(
        "--ours", nargs="+", default=[str(ROOT / "resources/weights/evfirenet.pt")],
        help="our checkpoints (several: one row each, named by their path)",
    )  # fmt: skip
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    setup_logging(None)
    torch.set_num_threads(args.threads)

    data = Path(args.data)
    if not data.is_file():
        conf = TrainConfig()
        t0 = time.perf_counter()
        generate_dataset(data, conf.data, {"heldout": conf.num_heldout_sequences}, seed=conf.seed)
        print(f"simulated the held-out split in {time.perf_counter() - t0:.0f} s -> {data}")

    methods: dict[str, str | None] = {}
    ours_names = []
    for path in args.ours:
        if not Path(path).is_file():
            print(f"skipping {path}: not found")
            continue
        name = "ours (evfirenet)" if len(args.ours) == 1 else f"ours ({path})"
        methods[name] = path
        ours_names.append(name)
    weights = Path(args.anchors) / "weights"
    for name, file in (("FireNet (published)", "firenet_1000.pth.tar"),
                       ("FireNet+ (published)", "firenet_plus.pth")):  # fmt: skip
        if (weights / file).is_file():
            methods[name] = str(weights / file)
        else:
            print(f"skipping {name}: {weights / file} not found")
    methods["highpass"] = None
    methods["integrate"] = None

    t0 = time.perf_counter()
    rows = evaluate_methods(data, methods, EvalConfig())
    print(f"\nHeld-out quality ({data.name}; {time.perf_counter() - t0:.0f} s)\n")
    print(format_table(rows))
    ssim = {r["method"]: r["ssim"] for r in rows}
    for mine in ours_names:
        for name in ("FireNet (published)", "FireNet+ (published)"):
            if name in ssim:
                verdict = ">=" if ssim[mine] >= ssim[name] else "<"
                print(f"{mine} SSIM {ssim[mine]:.4f} {verdict} {name} {ssim[name]:.4f}")


if __name__ == "__main__":
    main()
