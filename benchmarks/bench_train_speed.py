"""Training speed: seconds per step of our training recipe on a device, per batch size.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_train_speed.py
           [--device auto] [--steps 60] [--batch-sizes 4 16] [--data TRAINSET.h5] [--workers 2]

Runs :func:`evdense.training.train.train_model` with the default ``train`` settings (crops,
sequence length, truncated backpropagation, losses) except the batch size, for ``--steps`` steps
from scratch, and reads the step times from its ``history.jsonl``: the first ``log_every`` steps
(warm-up: allocator, cuDNN autotuning) are left out. Printed per batch size: seconds per step,
crop-windows per second (batch x sequence length / step time) and the final training loss.

The data set is ``--data`` (an existing training set, e.g. ``results/training/run2/
trainset_s0.h5``) or, without it, a small one simulated into a temporary folder from the default
recipe with planar scenes only (8 training and 2 validation sequences; it needs no open3d, so the
benchmark runs on a bare GPU machine). Step time does not depend on the scenes' content.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import tempfile
import time
from pathlib import Path

import torch

from evdense.log import setup_logging
from evdense.recon.inference import pick_device
from evdense.training.data import generate_dataset
from evdense.training.train import TrainConfig, describe_device, train_model


def step_times(history: Path, skip: int) -> tuple[float, float]:
    """(seconds per step after the first ``skip`` steps, last training loss) from a history."""
    recs = [json.loads(ln) for ln in history.read_text().splitlines() if ln.strip()]
    train = [r for r in recs if "train" in r]
    first = next(r for r in train if r["step"] >= skip)
    last = train[-1]
    per_step = (last["seconds"] - first["seconds"]) / max(1, last["step"] - first["step"])
    return per_step, last["train"]["loss"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto")
    ap.add_argument("--steps", type=int, default=60, help="steps timed per batch size (+ warm-up)")
    ap.add_argument("--batch-sizes", type=int, nargs="+", default=[4, 16])
    ap.add_argument("--data", help="an existing training set (.h5); default: simulate a small one")
    ap.add_argument("--workers", type=int, default=max(1, min(8, (os.cpu_count() or 2) - 1)))
    ap.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    args = ap.parse_args()
    setup_logging(level=logging.WARNING)
    dev = pick_device(args.device)
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        base = TrainConfig(device=str(dev), threads=args.threads)
        if args.data:
            data = Path(args.data)
        else:
            conf = TrainConfig.from_dict(
                {"num_train_sequences": 8, "num_val_sequences": 2, "num_heldout_sequences": 0,
                 "data": {"planar_fraction": 1.0}}
            )  # fmt: skip
            data = Path(tmp) / "trainset.h5"
            t0 = time.monotonic()
            generate_dataset(data, conf.data, conf.splits(), seed=1, workers=args.workers)
            print(f"simulated a planar set of 10 sequences in {time.monotonic() - t0:.0f} s")
        print(
            f"torch {torch.__version__} on {describe_device(dev)}; recipe: crops of "
            f"{base.crop_size} px, {base.sequence_length} windows, truncated backpropagation "
            f"over {base.tbptt_length}; {args.steps} timed steps after {base.log_every} warm-up"
        )
        print(f"{'batch':>6}{'s/step':>10}{'crop-windows/s':>16}{'loss':>9}")
        for bs in args.batch_sizes:
            skip = base.log_every
            conf = TrainConfig(
                device=str(dev), threads=args.threads, batch_size=bs,
                max_steps=skip + args.steps, val_every=10**9, checkpoint_every=10**9,
            )  # fmt: skip
            run = Path(tmp) / f"run_b{bs}"
            train_model(conf, data, run, run / "w.pt", resume=False)
            per_step, loss = step_times(run / "history.jsonl", skip)
            rate = bs * conf.sequence_length / per_step
            print(f"{bs:>6}{per_step:>10.3f}{rate:>16.0f}{loss:>9.4f}")
            if dev.type == "cuda":
                torch.cuda.empty_cache()


if __name__ == "__main__":
    main()
