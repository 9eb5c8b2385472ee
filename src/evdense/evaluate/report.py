"""The run's figures and its Markdown summary, from the gathered metrics table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from evdense.evaluate import figures
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


SWEEP_METRICS = (
    "refined_fscore",
    "dense_fscore",
    "sparse_fscore",
    "refined_chamfer",
    "ate_rmse_relative",
    "rpe_rot_rmse_deg",
    "sfm_registered_fraction",
    "image_ssim",
    "textured_psnr",
)
"""The metrics drawn against each swept quantity (those the table has)."""

SWEEP_AXES = ("speed", "dynamic_range", "window_events", "bins")
"""What a sweep varies: motion speed, dynamic range, events per window, voxel time bins."""


def with_sweep_columns(df: pd.DataFrame) -> pd.DataFrame:
    """The table plus ``window_events`` (the N of an ``n<N>`` window spec) for the window sweep."""
    d = df.copy()
    if "window" in d.columns:
        d["window_events"] = pd.to_numeric(
            d["window"].astype(str).str.extract(r"^n(\d+)$")[0], errors="coerce"
        )
    return d


def make_figures(df: pd.DataFrame, out_dir: str | Path) -> list[Path]:
    """The run's figures from its metrics table into ``out_dir`` (PNG + PDF): every metric against
    every quantity the run sweeps (speed, dynamic range, window size, bins), one line per image
    source with the oracle dashed, and the claim figure when the run checks the paper's claim.
    Pictures of each dataset come from its own rule (:mod:`evdense.evaluate.dataset_figures`)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    made: list[Path] = []
    if df.empty:
        return made
    d = with_sweep_columns(df)
    for x in SWEEP_AXES:
        if x not in d.columns or d[x].nunique() < 2:
            continue
        fixed = {k: 1.0 for k in ("speed", "dynamic_range") if k != x and k in d.columns}
        for metric in SWEEP_METRICS:
            if metric in d.columns and d[metric].notna().any():
                made += figures.plot_metric_vs(
                    d, x, metric, out_dir / f"{metric}_vs_{x}.png", hue="source", fixed=fixed
                )
    swept = any(k in d.columns and d[k].nunique() > 1 for k in ("speed", "dynamic_range"))
    claims = claim_table(df) if swept else pd.DataFrame()
    if not claims.empty:
        made += figures.claim_figure(
            claims, CLAIM_MARGIN, CLAIM_ORACLE_FRACTION, out_dir / "claim.png"
        )
    log.info("%d figure files in %s", len(made), out_dir)
    return made


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
