"""The ``evdense`` command.

Subcommands are registered in :data:`SUBCOMMANDS`: a name mapped to a function that adds its
arguments to an ``argparse`` sub-parser and sets ``func`` (called with the parsed arguments,
returns the exit status). To add one, write ``_add_<name>(sub)`` and a ``_run_<name>(args)``, and
add the name to the dict.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable

from evdense.log import get_logger, setup_logging

log = get_logger("cli")


# --- convert --------------------------------------------------------------------------------------
def _add_convert(sub: argparse.ArgumentParser) -> None:
    from evdense.io.detect import FORMATS

    sub.description = (
        "Convert an event recording (RPG text, E2VID HDF5, AEDAT4, ROS1 bag, Prophesee EVT2/EVT3/DAT, "
        "NumPy) to evdense's canonical HDF5 event file."
    )
    sub.add_argument("input", help="recording file (or a folder holding events.txt)")
    sub.add_argument("output", help="canonical event file to write (.h5)")
    sub.add_argument(
        "--format",
        default="auto",
        choices=("auto", *FORMATS),
        help="input format (default: from the file)",
    )
    sub.add_argument(
        "--width", type=int, help="sensor width in pixels (default: from the file, else inferred)"
    )
    sub.add_argument("--height", type=int, help="sensor height in pixels")
    sub.add_argument(
        "--calibration",
        help="intrinsics file (YAML, Kalibr/VINS YAML, COLMAP cameras.txt, RPG calib.txt)",
    )
    sub.add_argument(
        "--time-unit",
        default="auto",
        choices=("auto", "s", "ms", "us", "ns"),
        help="timestamp unit for text/HDF5/NumPy inputs",
    )
    sub.add_argument(
        "--unsorted",
        default="sort",
        choices=("sort", "error"),
        help="out-of-order timestamps: sort within the window, or fail",
    )
    sub.add_argument(
        "--reorder-window-us",
        type=int,
        default=10_000,
        help="how far back (us) an event may be and still be sorted",
    )
    sub.add_argument(
        "--out-of-bounds",
        default="error",
        choices=("error", "drop"),
        help="events outside the sensor: fail, or drop them",
    )
    sub.add_argument(
        "--compression",
        default="blosc-lz4",
        choices=("blosc-lz4", "zstd", "gzip", "lzf", "none"),
        help="HDF5 compression of the output (blosc-lz4: ~4 bytes/event, fastest to read)",
    )
    sub.add_argument("--topic", help="ROS bag: the EventArray topic (when there are several)")
    sub.add_argument(
        "--frames-dir",
        help="also write the recording's frames here (a frames folder is made inside)",
    )
    sub.add_argument(
        "--gt-dir",
        help="also write intrinsics.yaml / trajectory.txt here when the recording has them",
    )
    sub.add_argument("--manifest", help="also write a JSON manifest of what was found")
    sub.set_defaults(func=_run_convert)


def _run_convert(args: argparse.Namespace) -> int:
    from evdense.io.ingest import IngestConfig, ingest_recording

    cfg = IngestConfig(
        unsorted=args.unsorted,
        reorder_window_us=args.reorder_window_us,
        out_of_bounds=args.out_of_bounds,
        time_unit=args.time_unit,
        compression=args.compression,
    )
    res = ingest_recording(
        args.input,
        args.output,
        conventional_dir=args.frames_dir,
        gt_dir=args.gt_dir,
        manifest_out=args.manifest,
        fmt=args.format,
        calibration=args.calibration,
        width=args.width,
        height=args.height,
        config=cfg,
        reader_options={"topic": args.topic} if args.topic else None,
    )
    log.info(
        "%s -> %s: %d events, %dx%d, %.3f s",
        args.input,
        args.output,
        res.num_events,
        res.width,
        res.height,
        (res.t_end_us - res.t_start_us) * 1e-6,
    )
    return 0


# --- train --------------------------------------------------------------------------------------
def _add_train(sub: argparse.ArgumentParser) -> None:
    sub.description = (
        "Train our FireNet reconstruction weights on simulated data: simulate the training set "
        "(cached in RUN_DIR), train with checkpoints (resumes from the latest), keep the best "
        "validation weights, score them on held-out sequences."
    )
    sub.add_argument("run_dir", help="folder for the training set, checkpoints and history")
    sub.add_argument("--weights", help="where the best weights go (.pt; JSON beside it)")
    sub.add_argument("--config", help="YAML config whose `train` section sets the options")
    sub.add_argument("--seed", type=int, help="override train.seed")
    sub.add_argument("--max-steps", type=int, help="override train.max_steps")
    sub.add_argument("--time-budget-min", type=float, help="override train.time_budget_min")
    sub.add_argument("--workers", type=int, default=1, help="processes simulating the data")
    sub.add_argument("--no-resume", action="store_true", help="start over, ignoring checkpoints")
    sub.add_argument("--no-evaluate", action="store_true", help="skip the held-out evaluation")
    sub.set_defaults(func=_run_train)


def _run_train(args: argparse.Namespace) -> int:
    import yaml

    from evdense.training.train import TrainConfig, run_training

    section: dict = {}
    if args.config:
        with open(args.config) as f:
            section = dict((yaml.safe_load(f) or {}).get("train") or {})
    for key in ("seed", "max_steps", "time_budget_min"):
        if getattr(args, key) is not None:
            section[key] = getattr(args, key)
    res = run_training(
        TrainConfig.from_dict(section),
        args.run_dir,
        weights_path=args.weights,
        workers=args.workers,
        resume=not args.no_resume,
        evaluate=not args.no_evaluate,
    )
    log.info("trained %d steps; best step %d: %s", res.step, res.best_step, res.best_val)
    return 0


SUBCOMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None]]] = {
    "convert": ("convert a recording to the canonical event file", _add_convert),
    "train": ("train our reconstruction weights on simulated data", _add_train),
}


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every registered subcommand."""
    parser = argparse.ArgumentParser(
        prog="evdense", description="Event-camera recordings to dense 3D meshes."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--log-file", help="also write the log to this file")
    subs = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (help_text, add) in SUBCOMMANDS.items():
        add(subs.add_parser(name, help=help_text))
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``evdense`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    setup_logging(args.log_file, level=logging.DEBUG if args.verbose else logging.INFO)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as e:
        log.error("%s", e)
        return 2


if __name__ == "__main__":
    sys.exit(main())
