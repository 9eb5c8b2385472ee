"""``python -m evdense.sfm FRAMES_DIR OUT_DIR [--config sfm.yaml] [--threads N]``."""

from __future__ import annotations

import argparse
from pathlib import Path

from evdense.sfm.stage import run_sfm


def main(argv: list[str] | None = None) -> None:
    """``python -m evdense.sfm FRAMES_DIR OUT_DIR [--config sfm.yaml] [--threads N]``."""
    import yaml

    from evdense.log import setup_logging

    ap = argparse.ArgumentParser(
        prog="python -m evdense.sfm",
        description="Structure from motion on a frames folder with pycolmap.",
    )
    ap.add_argument("frames_dir")
    ap.add_argument("out_dir")
    ap.add_argument(
        "--config", help="YAML holding the sfm section (or a whole config with an 'sfm' key)"
    )
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args(argv)
    setup_logging()
    conf = {}
    if args.config:
        conf = yaml.safe_load(Path(args.config).read_text()) or {}
        conf = conf.get("sfm", conf)
    run_sfm(args.frames_dir, args.out_dir, conf, num_threads=args.threads)


if __name__ == "__main__":
    main()
