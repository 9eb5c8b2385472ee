"""Write the weights of a training run's resumable checkpoints as weights files the benchmarks read.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/export_checkpoints.py RUN_DIR [--out DIR]

For each ``RUN_DIR/checkpoints/step_*.pt`` (``train.keep_checkpoints`` of them are kept) this
writes ``DIR/step_N.pt`` (the trained weights) and, for a run with ``train.ema_decay``,
``DIR/step_N_ema.pt`` (their moving average), each with its JSON. The checkpoints of one run,
scored side by side with ``bench_recon_real.py --ours DIR/*.pt``, show how far a figure moves
between steps of one recipe, which a difference between recipes must exceed before it counts.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from evdense.training.train import export_state_weights


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--out", type=Path, help="default: RUN_DIR/exported")
    args = ap.parse_args()
    out = args.out or args.run_dir / "exported"
    states = sorted((args.run_dir / "checkpoints").glob("step_*.pt"))
    if not states:
        raise SystemExit(f"{args.run_dir}: no checkpoints/step_*.pt")
    for path in states:
        has_ema = "ema" in torch.load(path, map_location="cpu", weights_only=True)
        for averaged in (False, True) if has_ema else (False,):
            dest = out / f"{path.stem}{'_ema' if averaged else ''}.pt"
            print(export_state_weights(path, dest, averaged))


if __name__ == "__main__":
    main()
