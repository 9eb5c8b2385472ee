"""``python -m evdense.training RUN_DIR [--config CFG.yaml] [--workers N] ...``: the same command
as ``evdense train`` (see ``evdense train --help``)."""

from __future__ import annotations

import sys

from evdense.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
