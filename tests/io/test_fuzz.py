"""A fast subset of the reader fuzz (benchmarks/fuzz_readers.py runs the full 1,000 per seed)."""

from __future__ import annotations

from conftest import ANCHORS

from evdense.testing.fuzz import BAD_OUTCOMES, fuzz, make_seeds, warm_up


def test_mutated_recordings_fail_cleanly_or_read(tmp_path):
    # our writers' files in every format, plus the real anchors when they are here
    seeds = make_seeds(tmp_path / "seeds", ANCHORS if ANCHORS.is_dir() else None)
    assert len(seeds) >= 12
    warm_up()
    report = fuzz(seeds, 16, tmp_path, seed=2026)
    counts = {name: r["counts"] for name, r in report.items()}
    bad = {n: {k: c[k] for k in BAD_OUTCOMES if c[k]} for n, c in counts.items()}
    bad = {n: b for n, b in bad.items() if b}
    examples = [ex for r in report.values() for ex in r["examples"]]
    assert not bad, f"bad outcomes {bad}: {examples}"
    # the mutants are not all rejected by one trivial check: some still read, many fail cleanly
    assert sum(c["ok"] for c in counts.values()) > 0
    assert sum(c["clean"] for c in counts.values()) > len(seeds) * 8
