"""Event streams: the canonical container, windows, voxel grids and pictures of events."""

from evdense.events.container import EventFile, Events, EventWriter, write_events

__all__ = ["EventFile", "EventWriter", "Events", "write_events"]
