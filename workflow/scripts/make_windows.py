"""Snakemake adapter of rule make_windows: events.h5 -> windows_<spec>.h5 (spec from the file name)."""

from evdense.events.windows import make_windows, parse_window_spec
from evdense.log import setup_logging

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
make_windows(sm.input.events, sm.output.windows, parse_window_spec(sm.wildcards.win))
