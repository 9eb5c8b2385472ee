"""Shared fixtures: the real anchors (skipped when absent) and a seeded RNG."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
ANCHORS = Path(os.environ.get("EVDENSE_ANCHORS", REPO.parent / "shared" / "anchors"))


@pytest.fixture(scope="session")
def anchors() -> Path:
    """The folder of real recordings and published checkpoints; skips the test when absent."""
    if not ANCHORS.is_dir():
        pytest.skip(f"anchors folder not found at {ANCHORS} (set EVDENSE_ANCHORS)")
    return ANCHORS


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)
