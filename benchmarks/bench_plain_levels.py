"""Where plain (untextured) pixels sit in the reconstruction targets: training data vs a test scene.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_plain_levels.py TRAINSET.h5
           [--stability results/benchmarks/stability_lowtex.h5] [--every 4]

A pixel is plain when the 7 x 7 standard deviation of its frame, rescaled by the frame's own
1st-99th percentiles (as every quality figure is), is below 0.02; textured above 0.08. Pixels the
rescaling or the target's tone mapping clip to 0 or 1 are left out of the plain ones. Printed per
split of a training set (``evdense train``'s ``trainset_s*.h5``; an empty split is skipped) and for the low-texture room of
``bench_recon_stability.py`` (its log GT): the plain share of pixels, their mean and median level,
their share in each fifth of the range, and the summed absolute voxel per plain and per textured
pixel (how many events each kind sees per window). A network learns the levels plain regions
take from the first rows; the last row is what the stability figure asks of it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import h5py
import numpy as np
from scipy.ndimage import uniform_filter

from evdense.evaluate.images import normalize_intensity
from evdense.training.data import load_split


def plain_stats(frames: np.ndarray, voxels: np.ndarray, tone_mapped: bool) -> dict[str, object]:
    """Statistics of plain and textured pixels over ``frames`` ``(N, H, W)`` and their voxel
    grids ``(N, B, H, W)``; ``tone_mapped``: the frames are targets in [0, 1] (clipped ends)."""
    share, lv_plain, lv_tex, act_plain, act_tex = [], [], [], [], []
    for t, v in zip(frames.astype(np.float32), voxels, strict=True):
        r = normalize_intensity(t)
        m = uniform_filter(r, 7)
        sd = np.sqrt(np.maximum(uniform_filter(r * r, 7) - m * m, 0))
        inner = (r > 0.005) & (r < 0.995)
        if tone_mapped:
            inner &= (t > 0.001) & (t < 0.999)
        plain, tex = (sd < 0.02) & inner, sd > 0.08
        act = np.abs(v.astype(np.float32)).sum(0)
        share.append(plain.mean())
        lv_plain.append(r[plain])
        lv_tex.append(r[tex])
        act_plain.append(act[plain])
        act_tex.append(act[tex])
    lp = np.concatenate(lv_plain)
    fifths = np.histogram(lp, bins=5, range=(0, 1))[0] / max(len(lp), 1)
    return {
        "share": float(np.mean(share)),
        "mean": float(lp.mean()) if len(lp) else float("nan"),
        "median": float(np.median(lp)) if len(lp) else float("nan"),
        "fifths": fifths,
        "act_plain": float(np.concatenate(act_plain).mean()) if len(lp) else float("nan"),
        "act_tex": float(np.concatenate(act_tex).mean()),
        "textured_level": float(np.concatenate(lv_tex).mean()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trainset", type=Path, help="a training set file (trainset_s*.h5)")
    ap.add_argument(
        "--stability", type=Path, default=Path("results/benchmarks/stability_lowtex.h5"),
        help="the low-texture room of bench_recon_stability.py (skipped when absent)",
    )  # fmt: skip
    ap.add_argument("--every", type=int, default=4, help="use every n-th window from window 8")
    args = ap.parse_args()
    rows = []
    with h5py.File(args.trainset, "r") as f:  # runs made with num_heldout_sequences 0 have none
        splits = [s for s in ("train", "heldout") if s in f and len(f[s])]
    for split in splits:
        vox, tgt = load_split(args.trainset, split)
        rows.append(
            (f"{split} split ({len(tgt)} sequences)",
             plain_stats(tgt[:, 8 :: args.every].reshape(-1, *tgt.shape[2:]),
                         vox[:, 8 :: args.every].reshape(-1, *vox.shape[2:]), True))
        )  # fmt: skip
    if args.stability.is_file():
        with h5py.File(args.stability, "r") as f:
            logr, vox = f["log_radiance"][100::5], f["voxels"][100::5]
        rows.append(("low-texture room (stability, log GT)", plain_stats(logr, vox, False)))
    print("| data | plain share | plain level mean / median | plain share per fifth of the range "
          "| textured level mean | abs voxel per px, plain / textured |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- |")
    for name, s in rows:
        f = " / ".join(f"{x:.2f}" for x in s["fifths"])
        print(f"| {name} | {s['share']:.2f} | {s['mean']:.2f} / {s['median']:.2f} | {f} "
              f"| {s['textured_level']:.2f} | {s['act_plain']:.3f} / {s['act_tex']:.3f} |")  # fmt: skip


if __name__ == "__main__":
    main()
