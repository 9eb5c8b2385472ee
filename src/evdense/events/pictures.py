"""Pictures of events: the event frame (polarity-coloured accumulation) and the space-time plot.

These are the two standard figures of event-camera papers. Colours follow the common look:
positive events red, negative events blue, on a white (or black) background.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evdense.events.container import Events

POSITIVE_RGB = (214, 39, 40)  # red
NEGATIVE_RGB = (31, 119, 180)  # blue
BACKGROUNDS = {"white": (255, 255, 255), "black": (0, 0, 0)}


def polarity_counts(events: Events, height: int, width: int) -> np.ndarray:
    """Per-pixel counts of positive and negative events, int64 ``(2, height, width)`` (``[0]`` positive)."""
    x = np.asarray(events.x, np.intp)
    y = np.asarray(events.y, np.intp)
    if len(x) and (x.max() >= width or y.max() >= height):
        raise ValueError(f"events lie off the {width}x{height} sensor")
    pix = y * width + x
    pos = np.asarray(events.p) > 0
    hw = height * width
    counts = np.empty((2, hw), np.int64)
    counts[0] = np.bincount(pix[pos], minlength=hw)
    counts[1] = np.bincount(pix[~pos], minlength=hw)
    return counts.reshape(2, height, width)


def event_frame(events: Events, height: int, width: int, background: str = "white") -> np.ndarray:
    """Event frame: RGB uint8 ``(height, width, 3)`` of the events of one window.

    A pixel with events takes the mix of red (positive) and blue (negative) in proportion to its
    counts, so pure red or blue where one polarity fired, purple where both did; pixels without
    events keep the ``background`` (``white`` or ``black``).
    """
    if background not in BACKGROUNDS:
        raise ValueError(f"background must be one of {sorted(BACKGROUNDS)}, got {background!r}")
    c = polarity_counts(events, height, width).astype(np.float32)
    total = c[0] + c[1]
    img = np.empty((height, width, 3), np.float32)
    img[:] = BACKGROUNDS[background]
    hit = total > 0
    frac_pos = np.divide(c[0], total, out=np.zeros_like(total), where=hit)[hit][:, None]
    img[hit] = frac_pos * np.float32(POSITIVE_RGB) + (1.0 - frac_pos) * np.float32(NEGATIVE_RGB)
    return np.round(img).astype(np.uint8)


def save_event_frame(
    path: str | Path, events: Events, height: int, width: int, background: str = "white"
) -> Path:
    """Write the event frame of ``events`` as a PNG (one image pixel per sensor pixel)."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, event_frame(events, height, width, background))
    return path


def plot_space_time(
    path: str | Path,
    events: Events,
    height: int,
    width: int,
    max_events: int = 20000,
    seed: int = 0,
    title: str | None = None,
    pdf: bool = False,
) -> Path:
    """Space-time plot: a 3D scatter of events (x, t, y) coloured by polarity, as a PNG (and with
    ``pdf`` a PDF beside it, the points rasterised).

    ``events`` are drawn at random down to ``max_events`` (uniformly, so the density is kept);
    time is shown in milliseconds from the first event, rows increase downwards as in the image.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = len(events)
    if n > max_events:
        idx = np.sort(np.random.default_rng(seed).choice(n, max_events, replace=False))
        events = events[idx]
    t_ms = (events.t - (events.t[0] if len(events) else 0)) * 1e-3
    pos = events.p > 0
    fig = plt.figure(figsize=(7, 5.5))
    ax = fig.add_subplot(projection="3d")
    for m, rgb, label in ((pos, POSITIVE_RGB, "positive"), (~pos, NEGATIVE_RGB, "negative")):
        ax.scatter(
            events.x[m],
            t_ms[m],
            events.y[m],
            s=2.0,
            c=[np.array(rgb) / 255.0],
            alpha=1.0,
            linewidths=0,
            label=label,
            depthshade=False,
            rasterized=pdf,
        )
    ax.set_xlabel("x (px)")
    ax.set_ylabel("t (ms)")
    ax.set_zlabel("y (px)")
    ax.set_xlim(0, width)
    ax.set_zlim(height, 0)
    ax.set_box_aspect((width, max(width, height) * 1.5, height))
    ax.view_init(elev=20, azim=-60)
    ax.legend(loc="upper left", markerscale=4, frameon=False)
    ax.set_title(title or f"{n} events" + (f" ({len(events)} drawn)" if n > max_events else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    if pdf:
        fig.savefig(path.with_suffix(".pdf"), dpi=150)
    plt.close(fig)
    return path
