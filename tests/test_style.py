"""The code style the project keeps, checked where CI runs (``.ci/run`` runs only the tests)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool(name: str) -> str:
    exe = Path(sys.executable).with_name(name)
    found = str(exe) if exe.is_file() else shutil.which(name)
    if found is None:
        pytest.skip(f"{name} is not installed (pip install -e '.[dev]')")
    return found


@pytest.mark.parametrize(
    "args",
    [
        ["ruff", "check", "."],
        ["ruff", "format", "--check", "."],
        ["snakefmt", "--check", "workflow", "Snakefile"],
    ],
    ids=["ruff-check", "ruff-format", "snakefmt"],
)
def test_style(args):
    res = subprocess.run([_tool(args[0]), *args[1:]], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, f"{' '.join(args)} found problems:\n{res.stdout}{res.stderr}"
