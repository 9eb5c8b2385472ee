"""Frames reconstructed from a real ECD clip as windows accumulate: our weights beside FireNet.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/fig_recon_real_strip.py
           [--ours resources/weights/evfirenet.pt [more.pt ...]] [--anchors ../shared/anchors]
           [--clip slider_depth] [--events-per-pixel 0.046] [--frames 5]
           [--out docs/figures/ecd_slider_depth_strip.png]

Every method starts from an empty state on the clip (``slider_depth`` or one of the rotation
chunks ``boxes``, ``dynamic``, ``poster``, ``shapes``) in windows of ``events-per-pixel x 240 x 180``
events; small windows give many of them, so the strip shows how a method holds the intensity of
plain surfaces over time (drifting blotches, halos around edges) rather than only its first
frames. Each frame is rescaled by its own 1st-99th percentiles, as in the metric of
``bench_recon_real.py``; the last row holds the APS frame nearest each column's window (a
rotation chunk has one). Also prints each row's SSIM against that frame (best shift within 10 px).
"""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from evdense.evaluate.figures import save_figure
from evdense.evaluate.images import normalize_intensity
from evdense.evaluate.real_frames import (
    read_ecd_clip,
    read_rotation_clip,
    reconstruct_clip,
    shifted_metrics,
)
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.inference import NetworkReconstructor

ROOT = Path(__file__).resolve().parents[1]


def _nearest_frame(frames: list[tuple[int | None, np.ndarray]], t_us: int) -> np.ndarray:
    """The frame whose time is nearest ``t_us`` (the only one when the clip has no times)."""
    if len(frames) == 1 or frames[0][0] is None:
        return frames[0][1]
    return min(frames, key=lambda f: abs(int(f[0]) - t_us))[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ours", nargs="+", default=[str(ROOT / "resources/weights/evfirenet.pt")])
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--clip", default="slider_depth")
    ap.add_argument("--events-per-pixel", type=float, default=0.046)
    ap.add_argument("--frames", type=int, default=5, help="columns of the strip")
    ap.add_argument("--voxel-clip", type=float, default=3.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    data = Path(args.anchors) / "data"
    if args.clip == "slider_depth":
        clip = read_ecd_clip(data / "ecd_slider_depth")
    else:
        clip = read_rotation_clip(data / "ecd_rotation" / args.clip)
    methods = {Path(p).stem: p for p in args.ours}
    methods["FireNet (published)"] = str(Path(args.anchors) / "weights/firenet_1000.pth.tar")
    n = int(round(args.events_per_pixel * 240 * 180 / 1000)) * 1000

    rows: dict[str, list[np.ndarray]] = {}
    for name, path in methods.items():
        net = load_checkpoint(path).net
        ends, frames = reconstruct_clip(
            clip, lambda net=net: NetworkReconstructor(net, voxel_clip=args.voxel_clip), n
        )
        cols = np.unique(np.linspace(0, len(frames) - 1, args.frames).round().astype(int))
        refs = [_nearest_frame(clip.frames, int(ends[k])) for k in cols]
        rows[name] = [frames[k] for k in cols]
        ssim = [
            shifted_metrics(frames[k], ref, 10)["ssim"] for k, ref in zip(cols, refs, strict=True)
        ]
        print(f"{name}: windows {cols.tolist()}, SSIM vs the nearest APS frame "
              + " ".join(f"{s:.3f}" for s in ssim))  # fmt: skip
    fig, axes = plt.subplots(
        len(rows) + 1, len(cols), figsize=(2.0 * len(cols), 1.6 * (len(rows) + 1)), squeeze=False
    )
    for r, (name, imgs) in enumerate([*rows.items(), ("APS frame", refs)]):
        for c in range(len(cols)):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            if c < len(imgs):
                ax.imshow(normalize_intensity(imgs[c]), cmap="gray", vmin=0, vmax=1)
            else:
                ax.axis("off")
            if r == 0:
                ax.set_title(f"window {cols[c]}", fontsize=9)
            if c == 0:
                ax.set_ylabel(textwrap.fill(name, 18), fontsize=7)
    fig.suptitle(
        f"Real ECD {clip.name} (DAVIS240C), windows of {n} events, each method from an empty state",
        fontsize=10,
    )
    fig.tight_layout()
    out = args.out or str(ROOT / "docs" / "figures" / f"ecd_{args.clip}_strip.png")
    for p in save_figure(fig, out):
        print(f"wrote {p}")


if __name__ == "__main__":
    main()
