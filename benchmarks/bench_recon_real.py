"""Reconstruction on real events against real APS frames: our weights beside published FireNet(+).

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_recon_real.py
           [--ours resources/weights/evfirenet.pt [more.pt ...]] [--anchors ../shared/anchors]
           [--events-per-pixel 0.278 0.093] [--threads 2] [--trace]

Clips (real DAVIS240C recordings of the Event Camera Dataset, in the anchors folder; none of our
weights was ever tuned on them): ``slider_depth`` (its first 50,000 events and the APS frames of
the same 0.17 s) and the four ``*_rotation`` chunks (20-30 k events, one APS frame each). Every
method starts from an empty state on windows of ``events-per-pixel x 240 x 180`` events (0.278 is
the pipeline's default density: 25,000 events at 346 x 260), with its own input normalisation and
the pipeline's voxel clip. Metric: :mod:`evdense.evaluate.real_frames` (per-frame 1st-99th
percentile rescaling as in EVREAL, SSIM and MSE at the best shift within 10 pixels). Prints one
table per window size and the verdicts of issue 18 (ours >= FireNet on every clip, mean >= FireNet
+ 0.02); given several weights (e.g. the checkpoints of one run, from ``export_checkpoints.py``),
also the range of their means and each clip's lowest score, since a difference between recipes
counts only beyond what checkpoints of one recipe differ by. ``--trace`` also prints every frame's
SSIM with the index of its window, which shows whether a method improves or degrades as windows
accumulate (use small windows, e.g. ``--events-per-pixel 0.046``, to get many windows out of these
short clips).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from evdense.evaluate.real_frames import evaluate_clip, read_anchor_clips
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.inference import NetworkReconstructor

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ours", nargs="+", default=[str(ROOT / "resources/weights/evfirenet.pt")])
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--events-per-pixel", nargs="+", type=float, default=[0.278, 0.093])
    ap.add_argument("--voxel-clip", type=float, default=3.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--trace", action="store_true", help="print each frame's SSIM and window")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    try:
        clips = read_anchor_clips(Path(args.anchors) / "data")
    except FileNotFoundError as e:
        raise SystemExit(str(e)) from None
    # one row per checkpoint, named by its folder and file when there are several
    methods = {f"{Path(p).parent.name}/{Path(p).stem}" if len(args.ours) > 1 else "ours": p
               for p in args.ours}  # fmt: skip
    methods["FireNet"] = str(Path(args.anchors) / "weights/firenet_1000.pth.tar")
    methods["FireNet+"] = str(Path(args.anchors) / "weights/firenet_plus.pth")
    nets = {k: load_checkpoint(v).net for k, v in methods.items()}

    for epp in args.events_per_pixel:
        n = int(round(epp * 240 * 180 / 1000)) * 1000
        table: dict[str, dict[str, tuple[float, float]]] = {}
        for name, net in nets.items():
            for clip in clips:
                rows = evaluate_clip(
                    clip, lambda net=net: NetworkReconstructor(net, voxel_clip=args.voxel_clip), n
                )
                if args.trace:
                    cells = " ".join(f"w{r['window']}={r['ssim']:.3f}" for r in rows)
                    print(f"trace N={n} {name} {clip.name}: {cells}")
                table.setdefault(name, {})[clip.name] = (
                    float(np.mean([r["ssim"] for r in rows])),
                    float(np.mean([r["mse"] for r in rows])),
                )
        names = [c.name for c in clips]
        print(
            f"\nN = {n} events per window ({epp} events/pixel); SSIM (MSE), frames averaged per clip\n"
        )
        print("| method | " + " | ".join(names) + " | mean SSIM |")
        print("| --- " * (len(names) + 2) + "|")
        for name, row in table.items():
            cells = [f"{row[c][0]:.3f} ({row[c][1]:.3f})" for c in names]
            mean = np.mean([row[c][0] for c in names])
            print(f"| {name} | " + " | ".join(cells) + f" | {mean:.3f} |")
        fn = table["FireNet"]
        for name, row in table.items():
            if name.startswith("FireNet"):
                continue
            each = all(row[c][0] >= fn[c][0] for c in names)
            margin = np.mean([row[c][0] for c in names]) - np.mean([fn[c][0] for c in names])
            print(f"{name}: >= FireNet on every clip: {'yes' if each else 'no'}; "
                  f"mean margin {margin:+.3f} (target +0.02)")  # fmt: skip
        ours = [name for name in table if not name.startswith("FireNet")]
        if len(ours) > 1:
            means = [np.mean([table[o][c][0] for c in names]) for o in ours]
            lows = [min(table[o][c][0] for o in ours) for c in names]
            print(f"over the {len(ours)} weights given: mean SSIM {min(means):.3f} to "
                  f"{max(means):.3f} (their average {np.mean(means):.3f}); per clip the lowest "
                  + " / ".join(f"{v:.3f}" for v in lows))  # fmt: skip


if __name__ == "__main__":
    main()
