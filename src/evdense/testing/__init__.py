"""Helpers for tests and benchmarks: fixtures, fuzzing (not used by the pipeline itself)."""
