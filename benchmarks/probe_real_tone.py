"""Does the real-clip gap come from the tone space? Each network's frames remapped, then scored.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/probe_real_tone.py
           [--ours resources/weights/evfirenet.pt [more.pt ...]] [--anchors ../shared/anchors]
           [--events-per-pixel 0.278] [--threads 2]

Our networks are trained to predict log radiance (each sequence's robust range mapped to [0, 1]);
published FireNet was trained on pictures taken as intensity, and the DAVIS APS frames that
``bench_recon_real.py`` compares with are close to linear in intensity. The per-frame 1st-99th
percentile rescaling of the metric removes a gain and an offset, not a curve. This diagnostic
scores every network's frames, on the same clips and windows as ``bench_recon_real.py``, after
fixed monotonic remaps of its output ``x`` in [0, 1]:

- ``as is``;
- ``exp(g (x - 1))`` for g = 1, 2, 3, 4: the output read as log intensity over g natural-log units
  and turned into linear intensity (what a log-trained network would need against linear frames);
- ``log x``: the output read as linear intensity and turned into log (the reverse);
- and, last, the output as is against ``log(APS + 1 % of its maximum)``: the frames in our
  networks' own tone space.

No remap is chosen by this script and none is used by the pipeline: if one remap lifted every clip
for every network, the gap would be one of tone; where remaps trade one clip for another, it is not.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from evdense.evaluate.real_frames import read_anchor_clips, reconstruct_clip, score_clip
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.inference import NetworkReconstructor

ROOT = Path(__file__).resolve().parents[1]

REMAPS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "as is": lambda x: x,
    **{f"exp({g:g}(x-1))": (lambda x, g=g: np.exp(g * (x - 1.0))) for g in (1.0, 2.0, 3.0, 4.0)},
    "log x": lambda x: np.log(np.clip(x, 1e-3, None)),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ours", nargs="+", default=[str(ROOT / "resources/weights/evfirenet.pt")])
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--events-per-pixel", type=float, default=0.278)
    ap.add_argument("--voxel-clip", type=float, default=3.0)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    try:
        clips = read_anchor_clips(Path(args.anchors) / "data")
    except FileNotFoundError as e:
        raise SystemExit(str(e)) from None
    torch.set_num_threads(args.threads)
    log_clips = [
        dataclasses.replace(
            c, frames=[(t, np.log(img + 0.01 * max(img.max(), 1e-6))) for t, img in c.frames]
        )
        for c in clips
    ]
    methods = {f"{Path(p).parent.name}/{Path(p).stem}": p for p in args.ours}
    methods["FireNet"] = str(Path(args.anchors) / "weights/firenet_1000.pth.tar")
    n = int(round(args.events_per_pixel * 240 * 180 / 1000)) * 1000
    names = [c.name for c in clips]
    print(f"N = {n} events per window; SSIM per clip (frames averaged), then the mean\n")
    print("| network | remap | " + " | ".join(names) + " | mean |")
    print("| --- " * (len(names) + 3) + "|")
    for name, path in methods.items():
        net = load_checkpoint(path).net
        # each clip reconstructed once; every remap is scored on the same frames
        runs = [
            reconstruct_clip(
                c, lambda net=net: NetworkReconstructor(net, voxel_clip=args.voxel_clip), n
            )
            for c in clips
        ]
        rows = [(remap, clips, f) for remap, f in REMAPS.items()]
        rows.append(("as is, against log APS", log_clips, REMAPS["as is"]))
        for remap, cs, f in rows:
            ssim = [
                float(np.mean([r["ssim"] for r in score_clip(c, ends, [f(x) for x in frames])]))
                for c, (ends, frames) in zip(cs, runs, strict=True)
            ]
            cells = " | ".join(f"{s:.3f}" for s in ssim)
            print(f"| {name} | {remap} | {cells} | {np.mean(ssim):.4f} |")


if __name__ == "__main__":
    main()
