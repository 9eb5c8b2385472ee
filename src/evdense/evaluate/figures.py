"""The figures of a run, drawn with matplotlib (PNG at 150 dpi and PDF).

Of the run's table: :func:`plot_metric_vs` (a metric against a swept quantity, a line per image
source) and :func:`claim_figure`. Of one dataset (assembled by
:mod:`evdense.evaluate.dataset_figures`): :func:`events_spacetime_figure`,
:func:`event_frames_over_time`, :func:`frames_comparison`, :func:`panel_grid` (rendered
reconstructions), :func:`error_views`, :func:`prf_figure` and :func:`trajectory_figure`.
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
    "refined_fscore": "F-score of the refined mesh",
    "sparse_fscore": "F-score of the sparse points",
    "refined_chamfer": "Chamfer distance of the refined mesh (m)",
    "rpe_rot_rmse_deg": "RPE rotation RMSE (deg)",
    "textured_psnr": "PSNR of textured renders (dB)",
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
    hue: str = "source",
    fixed: dict | None = None,
) -> list[Path]:
    """One panel per scene: ``metric`` against ``x`` (speed, dynamic_range, window_events, bins),
    a line per ``hue`` (the oracle dashed, conventional frames dotted).

    ``fixed`` filters the table first (e.g. ``{"dynamic_range": 1}`` for the speed plot). A source
    that the swept quantity does not touch (the conventional and GT frames under a window or bin
    sweep) is drawn as a horizontal line at its value. Event sources of a window or bin sweep are
    grouped by method. Failed runs count as they were recorded (an F-score of 0 when SfM failed).
    """
    d = df.copy()
    for k, v in (fixed or {}).items():
        if k in d.columns and (d[k] == v).any():
            d = d[d[k] == v]
    if metric not in d.columns or d.empty:
        fig, ax = plt.subplots(figsize=(4, 3))
        ax.text(0.5, 0.5, f"no data for {metric}", ha="center", va="center")
        ax.axis("off")
        return save_figure(fig, out_png)
    if x in ("window_events", "bins") and "method" in d.columns:
        d[hue] = d["method"].where(d["source_kind"] == "events", d["source"])
    scenes = sorted(d["scene"].dropna().unique()) if "scene" in d.columns else [None]
    scenes = scenes or [None]
    fig, axes = plt.subplots(
        1, len(scenes), figsize=(4 * len(scenes), 3.2), squeeze=False, sharey=True
    )
    for ax, scene in zip(axes[0], scenes, strict=True):
        ds = d if scene is None else d[d["scene"] == scene]
        for key, g in ds.groupby(hue):
            style = _source_style(str(key))
            if g[x].notna().any():
                g = g.groupby(x)[metric].mean().sort_index()
                ax.plot(g.index, g.values, marker="o", label=str(key), **style)
            elif g[metric].notna().any():
                ax.axhline(float(g[metric].mean()), label=str(key), **style)
        if x in ("dynamic_range", "window_events"):
            ax.set_xscale("log")
        ax.set_xlabel(AXIS_LABELS.get(x, x.replace("_", " ")))
        ax.set_title(str(scene) if scene is not None else "")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel(METRIC_LABELS.get(metric, metric))
    axes[0, -1].legend(fontsize=7)
    return save_figure(fig, out_png)


AXIS_LABELS = {
    "speed": "motion speed (x the preset's)",
    "dynamic_range": "scene dynamic range",
    "window_events": "events per window",
    "bins": "voxel time bins",
}


def claim_figure(
    claims: pd.DataFrame, margin: float, oracle_fraction: float, out_png: str | Path
) -> list[Path]:
    """The paper's claim per scene and condition: the event frames' F-score margin over the
    conventional frames, and their fraction of the oracle's, each with the claim's bar."""
    labels = [f"{r.scene}\n{r.condition}" for r in claims.itertuples()]
    xs = np.arange(len(claims))
    fig, axes = plt.subplots(1, 2, figsize=(max(6, 1.1 * len(claims) + 3), 3.4))
    for ax, col, bar, what in (
        (axes[0], "margin", margin, "events - conventional (F-score)"),
        (axes[1], "of_oracle", oracle_fraction, "events / oracle (F-score)"),
    ):
        vals = claims[col].astype(float).fillna(0.0).to_numpy()
        colours = ["tab:green" if v >= bar else "tab:red" for v in vals]
        ax.bar(xs, vals, color=colours)
        ax.axhline(bar, color="k", ls="--", lw=1, label=f"claim: {bar:g}")
        ax.set_xticks(xs)
        ax.set_xticklabels(labels, fontsize=7, rotation=30, ha="right")
        ax.set_title(what, fontsize=9)
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, out_png)


def note_figure(text: str, out_png: str | Path) -> list[Path]:
    """A figure that only says why there is nothing to draw (so every expected file exists)."""
    fig, ax = plt.subplots(figsize=(5, 1.2))
    ax.text(0.5, 0.5, text, ha="center", va="center", fontsize=10)
    ax.axis("off")
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


def events_spacetime_figure(
    events_path: str | Path,
    out_png: str | Path,
    title: str = "",
    duration_ms: float = 30.0,
    max_events: int = 20_000,
) -> list[Path]:
    """Fig. 3 of the seed paper: the events of ``duration_ms`` in the middle of the recording in
    (x, t, y), coloured by polarity (:func:`evdense.events.pictures.plot_space_time`)."""
    from evdense.events.container import EventFile
    from evdense.events.pictures import plot_space_time

    with EventFile(events_path) as ef:
        mid = 0.5 * (ef.t_start_us + ef.t_end_us)
        half = duration_ms * 500.0
        ev = ef.read(ef.index_at(mid - half), ef.index_at(mid + half))
        H, W = ef.height, ef.width
    label = f"{title}: {len(ev):,} events in {duration_ms:g} ms"
    png = plot_space_time(out_png, ev, H, W, max_events, title=label, pdf=True)
    return [png, png.with_suffix(".pdf")]


def event_frames_over_time(
    events_path: str | Path, out_png: str | Path, title: str = "", num: int = 4,
    num_events: int = 25_000,
) -> list[Path]:  # fmt: skip
    """Fig. 4: event frames (polarity-coloured) of ``num`` windows spread over the recording."""
    from evdense.events.container import EventFile
    from evdense.events.pictures import event_frame

    with EventFile(events_path) as ef:
        n, H, W = ef.num_events, ef.height, ef.width
        starts = np.linspace(0, max(0, n - num_events), num + 2)[1:-1].astype(int)
        panels = []
        for s in starts:
            ev = ef.read(int(s), int(s) + num_events)
            dt = (ev.t[-1] - ev.t[0]) * 1e-3 if len(ev) else 0.0
            t0 = ev.t[0] * 1e-6 if len(ev) else 0.0
            panels.append((event_frame(ev, H, W), f"t = {t0:.2f} s, {len(ev):,} ev in {dt:.1f} ms"))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.0 * len(panels), 2.6), squeeze=False)
    for ax, (img, label) in zip(axes[0], panels, strict=True):
        ax.imshow(img)
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    fig.suptitle(f"{title}: event frames", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, out_png)


def panel_grid(
    rows: list[tuple[str, list[tuple[str, np.ndarray | None]]]],
    out_png: str | Path,
    title: str = "",
) -> list[Path]:
    """Images in a grid: one row per (label, panels), each panel (title, image or None)."""
    ncol = max((len(p) for _, p in rows), default=1)
    fig, axes = plt.subplots(
        len(rows), ncol, figsize=(2.3 * ncol, 2.0 * len(rows) + 0.4), squeeze=False
    )
    for r, (label, panels) in enumerate(rows):
        for c in range(ncol):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            for side in ax.spines.values():
                side.set_visible(False)
            if c < len(panels):
                name, img = panels[c]
                if img is not None:
                    ax.imshow(np.clip(img, 0, 1), cmap="gray" if np.ndim(img) == 2 else None)
                elif name:
                    ax.text(0.5, 0.5, "no model", ha="center", va="center", color="0.4")
                ax.set_title(name, fontsize=6.5)
            if c == 0:
                ax.set_ylabel(label, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, out_png)


ERROR_CMAP = "RdYlGn_r"
"""Distances: green well within the threshold, yellow at it, red beyond (capped at twice it)."""


def error_views(
    cells: list[tuple[str, np.ndarray, np.ndarray]], tau: float, out_png: str | Path, title: str
) -> list[Path]:
    """Distance-coloured renders in a 2-column grid: each cell (title, distance ``(H, W)`` in
    metres, NaN where nothing is seen; Lambert shade ``(H, W)``), one colour bar for all, running
    from 0 to twice the threshold ``tau``, with ``tau`` marked."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    norm = Normalize(0.0, 2.0 * tau)
    cmap = colormaps[ERROR_CMAP]
    ncol = 2
    nrow = (len(cells) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.8 * ncol, 2.8 * nrow), squeeze=False)
    for ax, (label, dist, shade) in zip(axes.flat, cells, strict=False):
        rgb = np.ones(dist.shape + (3,))
        m = np.isfinite(dist)
        rgb[m] = cmap(norm(np.minimum(dist[m], 2 * tau)))[:, :3] * (0.45 + 0.55 * shade[m][:, None])
        ax.imshow(rgb)
        within = float(np.mean(dist[m] < tau)) if m.any() else float("nan")
        ax.set_title(
            f"{label}\n{100 * within:.0f} % of the pixels within the threshold", fontsize=6.5
        )
        ax.axis("off")
    for ax in list(axes.flat)[len(cells) :]:
        ax.axis("off")
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    bar = fig.colorbar(sm, ax=axes.ravel().tolist(), fraction=0.03, pad=0.02)
    bar.ax.axhline(tau, color="k", lw=1.5)
    bar.set_ticks([0, tau, 2 * tau])
    bar.set_ticklabels(["0", f"threshold\n{1000 * tau:.1f} mm", f">= {2000 * tau:.1f} mm"])
    bar.ax.tick_params(labelsize=7)
    fig.suptitle(title, fontsize=9)
    return save_figure(fig, out_png)


def _source_style(name: str) -> dict:
    """The oracle (GT frames) dashed, conventional frames dotted, event sources solid."""
    if name in ("gt", "oracle"):
        return {"ls": "--", "color": "0.3"}
    if name == "conventional":
        return {"ls": ":", "color": "tab:orange"}
    return {"ls": "-"}


def prf_figure(
    relative_thresholds: np.ndarray,
    curves: dict[str, tuple[list[float], list[float], list[float]]],
    default_threshold: float,
    out_png: str | Path,
) -> list[Path]:
    """Precision, recall and F-score against the threshold (% of the GT diagonal), a line per source."""
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2), sharey=True)
    x = 100 * np.asarray(relative_thresholds)
    for name, (p, r, f) in curves.items():
        for ax, y in zip(axes, (p, r, f), strict=True):
            ax.plot(x, y, label=name, **_source_style(name))
    for ax, what in zip(axes, ("precision", "recall", "F-score"), strict=True):
        ax.set_xscale("log")
        ax.axvline(100 * default_threshold, color="0.6", lw=0.8)
        ax.set_xlabel("threshold (% of the GT bounding-box diagonal)")
        ax.set_title(what, fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.set_ylim(0, 1.02)
    axes[0].set_ylabel("refined mesh")
    axes[-1].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, out_png)


def trajectory_figure(
    gt_xyz: np.ndarray,
    tracks: dict[str, np.ndarray],
    ate_relative: dict[str, float | None],
    out_png: str | Path,
    title: str = "",
) -> list[Path]:
    """Top (x-y) and side (x-z) views of the GT path and each source's SfM camera centres after
    the evaluation's Sim(3); the ATE (RMSE / path length) of each source in the legend."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, (i, j), view in zip(axes, ((0, 1), (0, 2)), ("top (x-y)", "side (x-z)"), strict=True):
        ax.plot(gt_xyz[:, i], gt_xyz[:, j], color="k", lw=2, label="GT")
        for name, xyz in tracks.items():
            if len(xyz) == 0:
                continue
            ate = ate_relative.get(name)
            lab = f"{name} (ATE {100 * ate:.2f} %)" if ate is not None else name
            ax.plot(xyz[:, i], xyz[:, j], marker=".", ms=3, lw=0.8, label=lab,
                    **{k: v for k, v in _source_style(name).items() if k != "ls"})  # fmt: skip
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("xyz"[i] + " (m)")
        ax.set_ylabel("xyz"[j] + " (m)")
        ax.set_title(view, fontsize=9)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7)
    ates = ", ".join(
        f"{k} {100 * v:.2f} %" for k, v in ate_relative.items() if v is not None and np.isfinite(v)
    )
    fig.suptitle(f"{title}: SfM cameras after Sim(3); ATE RMSE / path length: {ates}", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, out_png)
