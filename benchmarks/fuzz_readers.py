"""Fuzz every recording reader: mutants of valid files, one forked process per case (issue 21).

Usage: PYTHONPATH=src .venv/bin/python benchmarks/fuzz_readers.py [--cases 1000] [--seed 0]
           [--anchors ../shared/anchors] [--work results/fuzz] [--only NAME ...]

Seeds: one small recording per format written by our writers (RPG text folder, its images.txt,
a zip of it, E2VID HDF5, our HDF5, AEDAT4, ROS1 bag, EVT2, EVT3, DAT, npz, npy) plus the real files
of the anchors (DVXplorer AEDAT4, Prophesee EVT2/EVT3, ROS1 and ROS2 bags, ECD text). Each case:
a seeded mutant through ``ingest_recording`` in a forked child under a 4 GiB address-space limit
and a 20 s alarm, then read back through the canonical file's checks. Prints a table of
outcomes per seed (see :mod:`evdense.testing.fuzz`) and the first bad examples, kept under
``--work``/bad. Targets: 0 crash, foreign, unnamed, timeout, memory and bigrss (> 2 GiB RSS).
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from evdense.testing.fuzz import BAD_OUTCOMES, OUTCOMES, fuzz, make_seeds, warm_up

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--work", default=str(ROOT / "results" / "fuzz"))
    ap.add_argument("--only", nargs="*")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # readers log their corrections; the table says enough
    work = Path(args.work)
    seeds = make_seeds(work / "seeds", args.anchors)
    if args.only:
        seeds = [s for s in seeds if s.name in args.only]
    warm_up()
    t0 = time.monotonic()
    report = fuzz(seeds, args.cases, work, seed=args.seed)
    secs = time.monotonic() - t0
    print(f"\n{args.cases} mutants per seed, {len(seeds)} seeds, {secs:.0f} s\n")
    print("| seed | " + " | ".join(OUTCOMES) + " | max RSS (MB) |")
    print("| --- " * (len(OUTCOMES) + 2) + "|")
    total = dict.fromkeys(OUTCOMES, 0)
    for name, r in report.items():
        for k, v in r["counts"].items():
            total[k] += v
        print(f"| {name} | " + " | ".join(str(r["counts"][k]) for k in OUTCOMES)
              + f" | {r['max_rss_mb']:.0f} |")  # fmt: skip
    print("| **all** | " + " | ".join(str(total[k]) for k in OUTCOMES) + " | |")
    for name, r in report.items():
        for ex in r["examples"]:
            print(f"{name}: {ex}")
    bad = sum(total[k] for k in BAD_OUTCOMES)
    print(f"\nbad outcomes: {bad} ({', '.join(f'{k} {total[k]}' for k in BAD_OUTCOMES)})")


if __name__ == "__main__":
    main()
