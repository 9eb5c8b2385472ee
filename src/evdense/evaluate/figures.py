"""The paper's figures, regenerated from any run (matplotlib; PNG and PDF).

- :func:`plot_metric_vs`: F-score / ATE / SSIM against speed or dynamic range, one line per source;
- :func:`frames_comparison`: reconstructed frames beside conventional and GT frames at the same times;
- :func:`event_frames_figure`: event frames of fast and HDR datasets side by side;
- :func:`renders_comparison`: renders of reconstructions from different sources, one viewpoint.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from evdense.formats.frames import frame_paths_and_times  # noqa: E402


def save_figure(fig, out_png: str | Path) -> list[Path]:
    """Save ``fig`` as PNG (150 dpi) and PDF beside it; returns both paths."""
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=150, bbox_inches="tight")
    pdf = out_png.with_suffix(".pdf")
    fig.savefig(pdf, bbox_inches="tight")
    plt.close(fig)
    return [out_png, pdf]


METRIC_LABELS = {
    "dense_fscore": "F-score of the dense cloud",
    "mesh_fscore": "F-score of the mesh",
    "ate_rmse_relative": "ATE RMSE / trajectory length",
    "image_ssim": "SSIM of frames vs GT",
    "sfm_registered_fraction": "frames registered",
}


def plot_metric_vs(
    df: pd.DataFrame,
    x: str,
    metric: str,
    out_png: str | Path,
    hue: str = "source_kind",
    fixed: dict | None = None,
) -> list[Path]:
    """One panel per scene: ``metric`` against ``x`` (speed or dynamic_range), a line per ``hue``.

    ``fixed`` filters the table first (e.g. ``{"dynamic_range": 1}`` for the speed plot). Failed
    runs count as they were recorded (an F-score of 0 when SfM failed).
    """
    d = df.copy()
    for k, v in (fixed or {}).items():
        if k in d.columns:
            d = d[d[k] == v]
    if metric not in d.columns or d.empty:
        fig, ax = plt.subplots(figsize=(4, 3))
        ax.text(0.5, 0.5, f"no data for {metric}", ha="center", va="center")
        ax.axis("off")
        return save_figure(fig, out_png)
    scenes = sorted(d["scene"].dropna().unique()) if "scene" in d.columns else [None]
    fig, axes = plt.subplots(
        1, len(scenes), figsize=(4 * len(scenes), 3.2), squeeze=False, sharey=True
    )
    for ax, scene in zip(axes[0], scenes, strict=True):
        ds = d if scene is None else d[d["scene"] == scene]
        for key, g in ds.groupby(hue):
            g = g.groupby(x)[metric].mean().sort_index()
            ax.plot(g.index, g.values, marker="o", label=str(key))
        if x == "dynamic_range":
            ax.set_xscale("log")
        ax.set_xlabel(x.replace("_", " "))
        ax.set_title(str(scene) if scene is not None else "")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel(METRIC_LABELS.get(metric, metric))
    axes[0, -1].legend(fontsize=8)
    return save_figure(fig, out_png)


def _nearest_frame(frames_dir: Path, t: float) -> np.ndarray:
    import imageio.v3 as iio

    paths, ts = frame_paths_and_times(frames_dir)
    img = iio.imread(paths[int(np.argmin(np.abs(ts - t)))])
    return img if img.ndim == 2 else img[..., :3].mean(-1)


def frames_comparison(
    sources: dict[str, str | Path],
    out_png: str | Path,
    times_s: list[float] | None = None,
    num: int = 4,
) -> list[Path]:
    """A grid of frames: one row per source (label -> frames folder), one column per time.

    Each cell shows the source's frame nearest in time; times default to ``num`` evenly spaced
    times over the span that all sources cover.
    """
    sources = {k: Path(v) for k, v in sources.items()}
    if times_s is None:
        spans = [frame_paths_and_times(p)[1] for p in sources.values()]
        lo, hi = max(s.min() for s in spans), min(s.max() for s in spans)
        times_s = list(np.linspace(lo, hi, num + 2)[1:-1]) if hi > lo else [lo]
    fig, axes = plt.subplots(
        len(sources), len(times_s), figsize=(2.6 * len(times_s), 2.1 * len(sources)), squeeze=False
    )
    for r, (label, p) in enumerate(sources.items()):
        for c, t in enumerate(times_s):
            ax = axes[r, c]
            ax.imshow(_nearest_frame(p, t), cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            if c == 0:
                ax.set_ylabel(label, fontsize=8)
            if r == 0:
                ax.set_title(f"t = {t:.2f} s", fontsize=8)
    fig.tight_layout()
    return save_figure(fig, out_png)


def event_frames_figure(
    datasets: dict[str, str | Path], out_png: str | Path, num_events: int = 25_000
) -> list[Path]:
    """Event frames (polarity-coloured) of the middle window of each dataset's event file."""
    from evdense.events.container import EventFile
    from evdense.events.frames import event_frame

    fig, axes = plt.subplots(1, len(datasets), figsize=(3.2 * len(datasets), 2.6), squeeze=False)
    for ax, (label, path) in zip(axes[0], datasets.items(), strict=True):
        with EventFile(path) as ef:
            mid = ef.num_events // 2
            ev = ef.read(max(0, mid - num_events // 2), mid + num_events // 2)
            ax.imshow(event_frame(ev, ef.height, ef.width))
            dt = (ev.t[-1] - ev.t[0]) * 1e-3 if len(ev) else 0
        ax.set_title(f"{label}\n{len(ev)} events in {dt:.1f} ms", fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    return save_figure(fig, out_png)


def renders_comparison(images: dict[str, np.ndarray], out_png: str | Path) -> list[Path]:
    """Renders of reconstructions (label -> image ``(H, W)`` or ``(H, W, 3)``) side by side."""
    fig, axes = plt.subplots(1, len(images), figsize=(3.2 * len(images), 2.6), squeeze=False)
    for ax, (label, img) in zip(axes[0], images.items(), strict=True):
        ax.imshow(img, cmap="gray" if np.ndim(img) == 2 else None)
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    return save_figure(fig, out_png)
