"""What the ``python -m evdense.<stage>`` entry points share: a parser with ``--config`` and
``-v``, parsing with logging set up, and the stage's config section read from a YAML file."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from evdense.log import setup_logging


def parser(prog: str, description: str, section: str) -> argparse.ArgumentParser:
    """An argument parser with ``--config`` (a YAML holding the ``section`` section, or a whole
    config with that key) and ``-v``."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument(
        "--config", help=f"YAML holding the `{section}` section (or a whole config with that key)"
    )
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    ap.set_defaults(section=section)
    return ap


def parse(ap: argparse.ArgumentParser, argv: list[str] | None = None) -> argparse.Namespace:
    """Parse the arguments and send the log to stderr (debug with ``-v``)."""
    args = ap.parse_args(argv)
    setup_logging(level=logging.DEBUG if args.verbose else logging.INFO)
    return args


def config_section(args: argparse.Namespace) -> dict[str, Any]:
    """The ``--config`` file's section for this stage (``{}`` without one: the defaults)."""
    import yaml

    if not args.config:
        return {}
    conf = yaml.safe_load(Path(args.config).read_text()) or {}
    if not isinstance(conf, dict):
        raise ValueError(f"{args.config}: expected a YAML mapping")
    return conf.get(args.section, conf)
