"""The ``evdense`` command.

Subcommands are registered in :data:`SUBCOMMANDS`: a name mapped to a function that adds its
arguments to an ``argparse`` sub-parser and sets ``func`` (called with the parsed arguments,
returns the exit status). To add one, write ``_add_<name>(sub)`` and a ``_run_<name>(args)``, and
add the name to the dict.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from evdense.log import get_logger, setup_logging

log = get_logger("cli")


# --- convert --------------------------------------------------------------------------------------
def _add_config_options(sub: argparse.ArgumentParser, cls: type, names: Sequence[str]) -> None:
    """Options ``--<name>`` for fields of the config dataclass ``cls``: default, choices (from a
    ``Literal``), type and help all from the dataclass, so that they are written once."""
    from evdense.config_schema import field_docs

    hints, docs = typing.get_type_hints(cls), field_docs(cls)
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    for name in names:
        hint = hints[name]
        choices = typing.get_args(hint) if typing.get_origin(hint) is typing.Literal else None
        sub.add_argument(
            "--" + name.replace("_", "-"),
            default=defaults[name],
            type=None if choices else hint,
            choices=choices,
            help=docs[name].replace("%", "%%") + " (default: %(default)s)",
        )
    sub.set_defaults(_config_names=tuple(names))


def _config_options(args: argparse.Namespace) -> dict[str, Any]:
    """The values of the options :func:`_add_config_options` added to this subcommand."""
    return {name: getattr(args, name) for name in args._config_names}


def _add_convert(sub: argparse.ArgumentParser) -> None:
    from evdense.io.detect import FORMATS
    from evdense.io.ingest import IngestConfig

    sub.description = (
        "Convert an event recording (RPG text, E2VID HDF5, AEDAT4, ROS 1/ROS 2 bag, Prophesee "
        "EVT2/EVT3/DAT, NumPy) to evdense's canonical HDF5 event file."
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
    _add_config_options(
        sub,
        IngestConfig,
        ("time_unit", "unsorted", "reorder_window_us", "out_of_bounds", "compression"),
    )
    sub.add_argument("--topic", help="ROS bag: the event topic (when there are several)")
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

    cfg = IngestConfig(**_config_options(args))
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
    sub.add_argument("--device", help="override train.device (cpu, cuda, auto)")
    sub.add_argument("--init-weights", help="override train.init_weights (fine-tune from these)")
    sub.add_argument("--workers", type=int, default=1, help="processes simulating the data")
    sub.add_argument("--no-resume", action="store_true", help="start over, ignoring checkpoints")
    sub.add_argument("--no-evaluate", action="store_true", help="skip the held-out evaluation")
    sub.set_defaults(func=_run_train)


def _run_train(args: argparse.Namespace) -> int:
    import yaml

    from evdense.training.stage import run_training
    from evdense.training.train import TrainConfig

    section: dict = {}
    if args.config:
        with open(args.config) as f:
            section = dict((yaml.safe_load(f) or {}).get("train") or {})
    for key in ("seed", "max_steps", "time_budget_min", "device", "init_weights"):
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


# --- info ---------------------------------------------------------------------------------------
def _add_info(sub: argparse.ArgumentParser) -> None:
    sub.description = (
        "Describe a recording without converting it: format, sensor size, duration, event count "
        "and rate, polarity balance, frames, calibration and ground truth found."
    )
    sub.add_argument("recording", help="recording file or folder")
    sub.add_argument("--format", default="auto", help="input format (default: from the file)")
    sub.add_argument("--topic", help="ROS bag: the event topic (when there are several)")
    sub.add_argument("--json", action="store_true", help="print JSON instead of text")
    sub.set_defaults(func=_run_info)


def recording_info(path: str, fmt: str = "auto", topic: str | None = None) -> dict:
    """What :func:`_run_info` prints, as a dict (the events are read once, nothing is written)."""
    import numpy as np

    from evdense.io import open_recording

    opts = {"topic": topic} if topic else {}
    with open_recording(path, fmt, **opts) as rec:
        n = on = 0
        t0 = t1 = None
        xmax = ymax = -1
        for b in rec.iter_events():
            if not len(b.t):
                continue
            n += len(b.t)
            on += int((np.asarray(b.p) > 0).sum())
            t0 = int(b.t[0]) if t0 is None else min(t0, int(b.t[0]))
            t1 = int(b.t[-1]) if t1 is None else max(t1, int(b.t[-1]))
            xmax, ymax = max(xmax, int(b.x.max())), max(ymax, int(b.y.max()))
        frames = 0
        frame_size = None
        for fr in rec.iter_frames():
            frames += 1
            if frame_size is None:
                if fr.image is not None:
                    shape = fr.image.shape
                else:
                    import imageio.v3 as iio

                    shape = iio.improps(fr.source).shape
                frame_size = (int(shape[1]), int(shape[0]))
        w = rec.width or xmax + 1
        h = rec.height or ymax + 1
        cam = rec.camera(w, h) if n else None
        traj = rec.trajectory()
        duration = (t1 - t0) * 1e-6 if n else 0.0
        return {
            "path": str(path),
            "format": rec.format,
            "sensor": [w, h],
            "sensor_from": "file" if rec.width else "max x, y + 1 (the file does not say)",
            "events": n,
            "duration_s": duration,
            "rate_ev_per_s": n / duration if duration > 0 else None,
            "on_fraction": on / n if n else None,
            "t_first_us": t0,
            "t_last_us": t1,
            "frames": frames,
            "frame_size": list(frame_size) if frame_size else None,
            "calibration": None
            if cam is None
            else {
                "model": getattr(cam, "model", ""),
                "fx": cam.fx,
                "fy": cam.fy,
                "cx": cam.cx,
                "cy": cam.cy,
            },  # fmt: skip
            "gt_poses": 0 if traj is None else len(traj.t),
            "imu": "not read (evdense does not use IMU data)",
            "metadata": {k: v for k, v in rec.metadata.items() if k != "topics"},
        }


def _run_info(args: argparse.Namespace) -> int:
    import json

    info = recording_info(args.recording, args.format, args.topic)
    if args.json:
        print(json.dumps(info, indent=2, default=str))
        return 0
    rate = info["rate_ev_per_s"]
    cal = info["calibration"]
    lines = [
        f"{info['path']}",
        f"  format        {info['format']}",
        f"  sensor        {info['sensor'][0]} x {info['sensor'][1]} ({info['sensor_from']})",
        f"  events        {info['events']:,} over {info['duration_s']:.3f} s"
        + (f" ({rate / 1e6:.3f} Mev/s)" if rate else ""),
        "  polarity      "
        + (f"{100 * info['on_fraction']:.1f} % ON" if info["on_fraction"] is not None else "-"),
        f"  frames        {info['frames']}"
        + (f" ({info['frame_size'][0]} x {info['frame_size'][1]})" if info["frame_size"] else ""),
        "  calibration   "
        + (
            f"fx {cal['fx']:.2f} fy {cal['fy']:.2f} cx {cal['cx']:.2f} cy {cal['cy']:.2f}"
            if cal
            else "none"
        ),  # fmt: skip
        f"  GT poses      {info['gt_poses']}",
        f"  IMU           {info['imu']}",
    ]
    print("\n".join(lines))
    return 0


# --- reconstruct ----------------------------------------------------------------------------------
def _add_reconstruct(sub: argparse.ArgumentParser) -> None:
    sub.description = (
        "Reconstruct one recording to the end (frames, SfM, dense cloud, meshes, evaluation when "
        "it carries ground truth): writes OUT/config.yaml and runs the workflow in OUT."
    )
    sub.add_argument("recording", help="recording file or folder")
    sub.add_argument("--calibration", help="intrinsics file (else the recording's own, if any)")
    sub.add_argument("--method", nargs="+", default=["ours"], help="reconstruction presets")
    sub.add_argument("--format", default="auto", help="input format (default: from the file)")
    sub.add_argument("--out", default="evdense_out", help="working folder (results/ go inside)")
    sub.add_argument("--cores", type=int, default=2, help="cores for Snakemake")
    sub.add_argument("--name", help="dataset name (default: from the recording's file name)")
    sub.add_argument("--dry-run", action="store_true", help="only show what would run")
    sub.set_defaults(func=_run_reconstruct)


def _dataset_name(path) -> str:
    import re
    from pathlib import Path

    stem = Path(path).name.split(".")[0] or "recording"
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", stem).lstrip("._-")
    return (name or "recording")[:100]


def _run_reconstruct(args: argparse.Namespace) -> int:
    from pathlib import Path

    import yaml

    from evdense.config import load_config
    from evdense.workflow import run_workflow

    rec = Path(args.recording).resolve()
    if not rec.exists():
        raise FileNotFoundError(f"{rec}: no such recording")
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    name = args.name or _dataset_name(rec)
    ds: dict = {"recording": str(rec), "format": args.format}
    if args.calibration:
        ds["calibration"] = str(Path(args.calibration).resolve())
    conf = {"datasets": {name: ds}, "reconstruct": {"methods": list(args.method)}}
    cfg_path = out / "config.yaml"
    cfg_path.write_text(yaml.safe_dump(conf, sort_keys=False))
    load_config(cfg_path)  # a bad recording or option fails here, naming the key
    ok = run_workflow(cfg_path, out, cores=args.cores, dry_run=args.dry_run)
    if not ok or args.dry_run:
        return 0 if ok else 1
    print_products(out / "results", name, rec)
    return 0


def print_products(results: Path, name: str, recording: Path | str = "") -> None:
    """Where a dataset's products are: per source its status, COLMAP model, dense cloud, textured
    meshes and metrics, then the mesh page and the run's summary."""
    from evdense.formats.layout import Layout
    from evdense.formats.status import is_failed

    layout = Layout(str(results))
    res = Path(layout.dataset(name))
    print(f"\nresults of {recording or name} in {res}:")
    for sfm in sorted(Path(layout.stage(name, "sfm")).iterdir()):
        src = sfm.name
        meshes = sorted((Path(layout.stage(name, "mesh")) / src).glob("*/textured/mesh.obj"))
        status = "SfM failed (see stats.json)" if is_failed(sfm) else "ok"
        print(f"  {src}: {status}")
        print(f"    COLMAP model   {sfm / 'sparse' / '0'}")
        print(f"    dense cloud    {layout.dense_cloud(name, src)}")
        for m in meshes:
            print(f"    textured mesh  {m}")
        metrics = Path(layout.metrics(name, src))
        if metrics.is_file():
            print(f"    metrics        {metrics}")
    if Path(layout.mesh_page(name)).is_file():
        print(f"  meshes page    {layout.mesh_page(name)}")
    summary = Path(results) / "summary" / "summary.md"
    if summary.is_file():
        print(f"  summary        {summary}")


SUBCOMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None]]] = {
    "convert": ("convert a recording to the canonical event file", _add_convert),
    "train": ("train our reconstruction weights on simulated data", _add_train),
    "info": ("describe a recording without converting it", _add_info),
    "reconstruct": ("reconstruct one recording to the textured mesh", _add_reconstruct),
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
