"""The run's figures and its Markdown summary, from the gathered metrics table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from evdense.evaluate import figures
from evdense.formats.frames import is_frames_dir
from evdense.log import get_logger

log = get_logger("report")

CLAIM_MARGIN = 0.15
"""The paper's claim in numbers: events beat conventional frames by this F-score margin ..."""
CLAIM_ORACLE_FRACTION = 0.85
"""... and reach this fraction of the oracle's (GT frames) F-score."""


def best_fscore_column(df: pd.DataFrame) -> str:
    """The F-score of the most finished product present: refined or plain mesh, else dense, else sparse."""
    for c in ("refined_fscore", "mesh_fscore", "dense_fscore", "sparse_fscore"):
        if c in df.columns and df[c].notna().any():
            return c
    return "sparse_fscore"


def make_figures(df: pd.DataFrame, results_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """All figures of a run into ``out_dir`` (PNG + PDF): metric curves, frames, event frames."""
    results_dir, out_dir = Path(results_dir), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    made: list[Path] = []
    if df.empty:
        return made
    fcol = best_fscore_column(df)
    for metric in (fcol, "ate_rmse_relative", "image_ssim", "sfm_registered_fraction"):
        if metric in df.columns and "speed" in df.columns:
            if df["speed"].nunique() > 1:
                made += figures.plot_metric_vs(
                    df,
                    "speed",
                    metric,
                    out_dir / f"{metric}_vs_speed.png",
                    fixed={"dynamic_range": 1.0},
                )
            if df["dynamic_range"].nunique() > 1:
                made += figures.plot_metric_vs(
                    df,
                    "dynamic_range",
                    metric,
                    out_dir / f"{metric}_vs_dynamic_range.png",
                    fixed={"speed": 1.0},
                )
    synthetic = df.dropna(subset=["speed"]) if "speed" in df.columns else df.iloc[0:0]
    picks = {}
    if not synthetic.empty:
        picks["fastest"] = synthetic.sort_values(["speed", "dynamic_range"]).iloc[-1]["dataset"]
        picks["highest_dynamic_range"] = synthetic.sort_values(["dynamic_range", "speed"]).iloc[-1][
            "dataset"
        ]
    for label, dataset in picks.items():
        rows = df[df["dataset"] == dataset]
        sources = {}
        for src in sorted(rows["source"], key=lambda s: (s in ("conventional", "gt"), s)):
            folder = _frames_dir(results_dir, dataset, src)
            if is_frames_dir(folder):
                sources[src] = folder
        if len(sources) >= 1:
            made += figures.frames_comparison(sources, out_dir / f"frames_{label}_{dataset}.png")
    events = {f"{k}: {v}": results_dir / v / "events" / "events.h5" for k, v in picks.items()}
    events = {k: v for k, v in events.items() if v.exists()}
    if events:
        made += figures.event_frames_figure(events, out_dir / "event_frames.png")
    log.info("%d figure files in %s", len(made), out_dir)
    return made


def _frames_dir(results_dir: Path, dataset: str, source: str) -> Path:
    if source in ("gt", "oracle", "conventional"):
        return (
            results_dir
            / dataset
            / ("gt" if source != "conventional" else "conventional")
            / "frames"
        )
    return results_dir / dataset / "frames" / source


def claim_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per scene: event vs conventional vs oracle F-score at the fastest speed and at the highest
    dynamic range, and whether the paper's claim holds there.

    The claim holds when the best event source beats the conventional frames by
    :data:`CLAIM_MARGIN` and reaches :data:`CLAIM_ORACLE_FRACTION` of the oracle. The frames each
    source gave to SfM are listed beside the scores. The simulator gives the oracle at least
    ``simulator.render.gt_min_frames`` GT frames however fast the motion; where an oracle still
    reconstructed nothing, ``note`` says so, since "85 % of the oracle" is then no test at all.
    """
    fcol = best_fscore_column(df)
    rows = []
    if "scene" not in df.columns:
        return pd.DataFrame()

    def best(top: pd.DataFrame, kind: str) -> tuple[float, float]:
        sel = top[top["source_kind"] == kind]
        if sel.empty or sel[fcol].isna().all():
            return float("nan"), float("nan")
        r = sel.loc[sel[fcol].idxmax()]
        n = r.get("sfm_num_selected", r.get("sfm_num_frames", float("nan")))
        return float(r[fcol]), float(n) if n is not None else float("nan")

    for scene, g in df.dropna(subset=["scene"]).groupby("scene"):
        for condition, key in (
            ("fastest speed", "speed"),
            ("highest dynamic range", "dynamic_range"),
        ):
            other = "dynamic_range" if key == "speed" else "speed"
            base = g[g[other] == 1.0] if (g[other] == 1.0).any() else g
            top = base[base[key] == base[key].max()]
            (ev, ev_n), (conv, conv_n), (oracle, oracle_n) = (
                best(top, k) for k in ("events", "conventional", "gt")
            )
            holds = bool(
                np.isfinite(ev)
                and np.isfinite(conv)
                and ev - conv >= CLAIM_MARGIN
                and np.isfinite(oracle)
                and ev >= CLAIM_ORACLE_FRACTION * oracle
            )
            note = ""
            if np.isfinite(oracle) and oracle <= 0:
                note = f"the oracle reconstructed nothing from {oracle_n:.0f} frames"
            rows.append(
                {
                    "scene": scene,
                    "condition": condition,
                    key: top[key].iloc[0] if len(top) else None,
                    "events": ev,
                    "conventional": conv,
                    "oracle": oracle,
                    "margin": ev - conv,
                    "of_oracle": ev / oracle if np.isfinite(oracle) and oracle > 0 else np.nan,
                    "frames_events": ev_n,
                    "frames_conventional": conv_n,
                    "frames_oracle": oracle_n,
                    "claim_holds": holds,
                    "note": note,
                }
            )
    return pd.DataFrame(rows)


def write_summary(df: pd.DataFrame, out_md: str | Path) -> Path:
    """A short Markdown account of the run: the main table and the paper's claim checked."""
    from evdense.evaluate.table import markdown_table

    fcol = best_fscore_column(df)
    lines = ["# evdense run summary", ""]
    lines.append(
        f"{len(df)} runs over {df['dataset'].nunique() if not df.empty else 0} datasets. "
        f"F-scores are `{fcol}` at the default threshold."
    )
    lines += ["", "## All runs", "", markdown_table(df)]
    claims = claim_table(df)
    lines += [
        "## The paper's claim",
        "",
        f"Events beat conventional frames by at least {CLAIM_MARGIN} F-score and reach "
        f"{CLAIM_ORACLE_FRACTION:.0%} of the oracle, at the fastest speed and the highest dynamic range.",
        "",
    ]
    if claims.empty:
        lines.append("_Not checked: the run has no sweep over speed or dynamic range._")
    else:
        lines.append(markdown_table(claims, list(claims.columns)))
    Path(out_md).parent.mkdir(parents=True, exist_ok=True)
    Path(out_md).write_text("\n".join(lines) + "\n")
    return Path(out_md)
