"""Per-dataset summary of an event recording: counts, rate over time, polarity balance, pictures.

One streaming pass over the canonical file (bounded memory), then a folder with ``summary.json``,
``rate.png`` (event rate over time per polarity), ``event_frame_<k>.png`` for a few windows and
``spacetime.png``.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evdense.events.container import EventFile
from evdense.events.pictures import NEGATIVE_RGB, POSITIVE_RGB, plot_space_time, save_event_frame
from evdense.events.windows import WindowConfig, compute_windows, window_spec
from evdense.log import get_logger

log = get_logger("events.summary")

# The rate histogram widens its bins rather than hold more than this many (long recordings).
_MAX_RATE_BINS = 100_000
_CHUNK = 1 << 21


@dataclass(frozen=True)
class SummaryConfig:
    """What the per-dataset event summary computes and draws."""

    rate_bin_ms: float = 10.0
    """Width of the time bins of the event-rate plot, in milliseconds."""
    num_event_frames: int = 4
    """Event frames drawn, of windows evenly spaced over the recording."""
    background: str = "white"
    """Background of event frames: ``white`` or ``black``."""
    spacetime_duration_ms: float = 200.0
    """Time span of the space-time plot, in milliseconds, centred in the recording."""
    spacetime_max_events: int = 20000
    """Events drawn at most in the space-time plot (random subsample)."""

    def __post_init__(self) -> None:
        if not self.rate_bin_ms > 0 or not self.spacetime_duration_ms > 0:
            raise ValueError("summary durations must be > 0 ms")
        if self.num_event_frames < 0 or self.spacetime_max_events < 1:
            raise ValueError("summary num_event_frames must be >= 0 and spacetime_max_events >= 1")
        if self.background not in ("white", "black"):
            raise ValueError(f"summary background must be white or black, got {self.background!r}")


def event_statistics(ef: EventFile, rate_bin_ms: float) -> dict[str, Any]:
    """Counts, polarity balance, per-pixel activity and the event-rate histogram, in one pass.

    Returns a dict of plain numbers plus ``rate_edges_s`` (bin edges, seconds from the first event)
    and ``rate_pos``/``rate_neg`` (events per second in each bin) as numpy arrays.
    """
    t0 = ef.t_start_us
    span = max(1, ef.t_end_us - t0 + 1)
    bin_us = max(1.0, rate_bin_ms * 1000.0)
    nb = int(np.ceil(span / bin_us))
    if nb > _MAX_RATE_BINS:
        bin_us = span / _MAX_RATE_BINS
        nb = _MAX_RATE_BINS
        log.info("rate plot: bins widened to %.1f ms to keep %d bins", bin_us / 1000, nb)
    hist = np.zeros((2, nb), np.int64)
    pix = np.zeros(ef.width * ef.height, np.int64)
    for ev in ef.iter_chunks(_CHUNK):
        b = np.minimum(((ev.t - t0) / bin_us).astype(np.int64), nb - 1)
        pos = ev.p > 0
        hist[0] += np.bincount(b[pos], minlength=nb)
        hist[1] += np.bincount(b[~pos], minlength=nb)
        pix += np.bincount(ev.y.astype(np.intp) * ef.width + ev.x, minlength=pix.size)
    n = ef.num_events
    n_pos = int(hist[0].sum())
    dur = (ef.t_end_us - ef.t_start_us) * 1e-6
    rate = hist / (bin_us * 1e-6)
    return {
        "num_events": n,
        "num_positive": n_pos,
        "num_negative": n - n_pos,
        "positive_fraction": n_pos / n if n else float("nan"),
        "t_start_us": ef.t_start_us,
        "t_end_us": ef.t_end_us,
        "duration_s": dur,
        "mean_rate_ev_per_s": n / dur if dur > 0 else float("nan"),
        "peak_rate_ev_per_s": float(rate.sum(axis=0).max()) if nb else 0.0,
        "rate_bin_ms": bin_us / 1000.0,
        "width": ef.width,
        "height": ef.height,
        "events_per_pixel": n / pix.size,
        "active_pixel_fraction": float((pix > 0).mean()),
        "max_events_at_one_pixel": int(pix.max()),
        "rate_edges_s": np.arange(nb + 1) * bin_us * 1e-6,
        "rate_pos": rate[0],
        "rate_neg": rate[1],
    }


def plot_event_rate(path: str | Path, stats: dict[str, Any], title: str = "") -> Path:
    """Event rate over time (events/s, positive and negative) from :func:`event_statistics`, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    edges = stats["rate_edges_s"]
    fig, ax = plt.subplots(figsize=(8, 3.2))
    for r, rgb, label in (
        (stats["rate_pos"], POSITIVE_RGB, "positive"),
        (stats["rate_neg"], NEGATIVE_RGB, "negative"),
    ):
        ax.stairs(r, edges, color=np.array(rgb) / 255.0, label=label, linewidth=0.8)
    ax.stairs(stats["rate_pos"] + stats["rate_neg"], edges, color="0.2", label="all", linewidth=0.8)
    ax.set_xlabel("time from first event (s)")
    ax.set_ylabel(f"events / s ({stats['rate_bin_ms']:g} ms bins)")
    ax.set_xlim(edges[0], edges[-1])
    ax.set_ylim(bottom=0)
    ax.legend(frameon=False, ncols=3, loc="lower right", bbox_to_anchor=(1.0, 1.0))
    ax.set_title(title or f"{stats['num_events']} events, {stats['duration_s']:.3f} s", loc="left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# Over 80 lines on purpose: the summary's products in order (rate plot, event frames of chosen
# windows, space-time plot, summary.json) written into one staging folder that replaces the
# output only when all are made.
def summarize_events(
    events_path: str | Path,
    out_dir: str | Path,
    conf: SummaryConfig | None = None,
    window: WindowConfig | None = None,
) -> Path:
    """Stage: summary folder of a recording (``summary.json``, ``rate.png``, event frames, space-time plot).

    ``window``: the windows whose event frames are drawn (default: the ``events`` default windows).
    The folder is built under a temporary name and renamed when complete.
    """
    conf = conf or SummaryConfig()
    window = window or WindowConfig()
    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        with EventFile(events_path) as ef:
            if ef.num_events == 0:
                raise ValueError(
                    f"{events_path}: the event file holds no events; nothing to summarise"
                )
            stats = event_statistics(ef, conf.rate_bin_ms)
            name = Path(events_path).parent.parent.name  # results/{dataset}/events/events.h5
            title = f"{name}: {stats['num_events']} events, {stats['duration_s']:.3f} s"
            plot_event_rate(tmp / "rate.png", stats, title=title)
            wins = compute_windows(ef, window)
            picks = np.unique(
                np.linspace(0, len(wins) - 1, conf.num_event_frames).round().astype(int)
            )
            frames = []
            for j, k in enumerate(picks[: conf.num_event_frames]):
                ev = ef.read(int(wins.i0[k]), int(wins.i1[k]))
                name = f"event_frame_{j}.png"
                save_event_frame(tmp / name, ev, ef.height, ef.width, conf.background)
                frames.append(
                    {
                        "file": name,
                        "window": int(k),
                        "t_start_us": int(wins.t_start_us[k]),
                        "t_end_us": int(wins.t_end_us[k]),
                        "count": int(wins.count[k]),
                    }
                )
            mid = 0.5 * (ef.t_start_us + ef.t_end_us)
            half = conf.spacetime_duration_ms * 500.0
            st = ef.read(ef.index_at(mid - half), ef.index_at(mid + half))
            if len(st) == 0:
                st = ef.read(0, conf.spacetime_max_events)
            plot_space_time(
                tmp / "spacetime.png", st, ef.height, ef.width, conf.spacetime_max_events
            )
            counts = wins.count
            durs_ms = (wins.t_end_us - wins.t_start_us) * 1e-3
        summary = {k: v for k, v in stats.items() if not isinstance(v, np.ndarray)}
        summary.update(
            {
                "source": str(events_path),
                "windows": {
                    "spec": window_spec(window),
                    "num_windows": len(wins),
                    "median_events": float(np.median(counts)),
                    "median_duration_ms": float(np.median(durs_ms)),
                    "max_duration_ms": float(durs_ms.max()),
                },
                "event_frames": frames,
                "spacetime": {"file": "spacetime.png", "num_events": len(st)},
                "rate_plot": "rate.png",
                "config": asdict(conf),
            }
        )
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    log.info(
        "%s: %d events over %.3f s, %.1f%% positive -> %s",
        events_path,
        summary["num_events"],
        summary["duration_s"],
        100 * summary["positive_fraction"],
        out_dir,
    )
    return out_dir
