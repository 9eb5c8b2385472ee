"""Frames reconstructed from the real DVXplorer recording: our weights beside published FireNet.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/fig_dvxplorer_strip.py
           [--anchors ../shared/anchors] [--events-per-window 10000] [--frames 6]
           [--out docs/figures/dvxplorer_strip.png]

Runs the pipeline's own stage functions on ``anchors/data/dvxplorer_sample.aedat4`` (320x240,
111,954 events, a person in front of a wall, camera nearly still): ingest to the canonical event
file, windows of N events, 5-bin voxel grids (with the stage's default hot-pixel filter, which
masks this sensor's few dozen hot pixels; before it, our model drew each as a dot in a ring), then
``run_recon`` once per method with the stage's default options. Writes a strip (rows: methods, columns: evenly spaced windows) as PNG and
PDF, and prints per method the ms per frame and the mean contrast (standard deviation) of the
frames, so that an empty or flat reconstruction shows in numbers as well as in the picture.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from evdense.evaluate.figures import save_figure
from evdense.events.voxel import VoxelConfig, VoxelFile, make_voxels
from evdense.events.windows import WindowConfig, make_windows
from evdense.io.ingest import ingest_recording
from evdense.log import setup_logging
from evdense.recon.config import ReconstructConfig
from evdense.recon.stage import run_recon

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--events-per-window", type=int, default=10_000)
    ap.add_argument("--frames", type=int, default=6, help="columns of the strip")
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "dvxplorer_strip.png"))
    args = ap.parse_args()
    setup_logging(None)
    anchors = Path(args.anchors)
    recording = anchors / "data" / "dvxplorer_sample.aedat4"
    if not recording.is_file():
        raise SystemExit(f"{recording} not found (give --anchors)")

    methods = {"ours": str(ROOT / "resources" / "weights" / "evfirenet.pt")}
    firenet = anchors / "weights" / "firenet_1000.pth.tar"
    if firenet.is_file():
        methods["firenet"] = str(firenet)
    titles = {"ours": "ours (evfirenet)", "firenet": "FireNet (published)"}

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t_first = ingest_recording(recording, tmp / "events.h5").t_start_us * 1e-6
        make_windows(
            tmp / "events.h5", tmp / "windows.h5", WindowConfig(num_events=args.events_per_window)
        )
        make_voxels(tmp / "events.h5", tmp / "windows.h5", tmp / "voxels.h5", VoxelConfig(bins=5))
        with VoxelFile(tmp / "voxels.h5") as vf:
            print(f"hot pixels masked: {len(vf.hot_pixels)}")
        frames: dict[str, list[np.ndarray]] = {}
        times: list[float] = []
        for name, ckpt in methods.items():
            t0 = time.perf_counter()
            out = run_recon(
                tmp / "voxels.h5",
                tmp / name,
                ReconstructConfig(method=name, checkpoint=ckpt),
                num_threads=2,
            )
            pngs = sorted(out.glob("*.png"))
            ms = 1e3 * (time.perf_counter() - t0) / len(pngs)
            frames[name] = [np.asarray(Image.open(p), np.float32) / 255 for p in pngs]
            lines = (out / "timestamps.txt").read_text().splitlines()
            times = [float(ln.split()[1]) - t_first for ln in lines]  # from the first event
            contrast = np.mean([f.std() for f in frames[name][len(pngs) // 2 :]])
            print(
                f"{name:<8} {len(pngs)} frames, {ms:.0f} ms/frame incl. I/O, mean std {contrast:.3f}"
            )

    n = len(next(iter(frames.values())))
    cols = np.unique(np.linspace(1, n - 1, args.frames).round().astype(int))
    fig, axes = plt.subplots(
        len(frames), len(cols), figsize=(2.2 * len(cols), 1.8 * len(frames)), squeeze=False
    )
    for r, (name, imgs) in enumerate(frames.items()):
        for c, k in enumerate(cols):
            ax = axes[r, c]
            ax.imshow(imgs[k], cmap="gray", vmin=0, vmax=1)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(f"t = {times[k]:.2f} s", fontsize=9)
            if c == 0:
                ax.set_ylabel(titles.get(name, name), fontsize=9)
    fig.suptitle(
        f"Real DVXplorer recording (320x240), windows of {args.events_per_window} events",
        fontsize=10,
    )
    fig.tight_layout()
    for p in save_figure(fig, args.out):
        print(f"wrote {p}")


if __name__ == "__main__":
    main()
