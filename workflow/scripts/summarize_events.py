"""Snakemake adapter of rule summarize_events: events.h5 -> summary folder (JSON, rate plot, pictures)."""

from evdense.events.summary import SummaryConfig, summarize_events
from evdense.events.windows import WindowConfig
from evdense.log import setup_logging

sm = snakemake  # noqa: F821 (injected by Snakemake)
setup_logging(sm.log[0])
summarize_events(
    sm.input.events,
    sm.output.summary,
    SummaryConfig(**sm.params.summary),
    WindowConfig.from_dict(sm.params.window),
)
