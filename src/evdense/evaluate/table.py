"""Gather the metrics files of all runs into one table (pandas; CSV and Markdown)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd


def _pick(values: list[float], thresholds: list[float], rel: float) -> float:
    for r, v in zip(thresholds, values, strict=True):
        if abs(r - rel) < 1e-12:
            return v
    return float("nan")


def metrics_row(metrics: dict, default_threshold: float | None = None) -> dict:
    """Flatten one metrics JSON into a table row (labels, SfM counts, ATE, F-scores, image scores)."""
    row = dict(metrics.get("labels", {}))
    rel = (
        default_threshold
        if default_threshold is not None
        else metrics.get("config", {}).get("default_threshold", 0.01)
    )
    row["failed"] = bool(metrics.get("failed", False))
    for k, v in (metrics.get("sfm") or {}).items():
        row[f"sfm_{k}"] = v
    traj = metrics.get("trajectory") or {}
    for k in ("ate_rmse", "ate_rmse_relative", "rpe_trans_rmse", "rpe_rot_rmse_deg", "scale"):
        row[k] = traj.get(k)
    for name, g in (metrics.get("geometry") or {}).items():
        row[f"{name}_points"] = g["num_points"]
        row[f"{name}_fscore"] = _pick(g["fscore"], g["relative_thresholds"], rel)
        row[f"{name}_precision"] = _pick(g["precision"], g["relative_thresholds"], rel)
        row[f"{name}_recall"] = _pick(g["recall"], g["relative_thresholds"], rel)
        row[f"{name}_accuracy"] = g["accuracy_median"]
        row[f"{name}_completeness"] = g["completeness_median"]
        row[f"{name}_chamfer"] = g["chamfer"]
    for k, v in (metrics.get("images") or {}).items():
        row[f"image_{k}"] = v
    for k, v in (metrics.get("textured_renders") or {}).items():
        row[f"textured_{k}"] = v
    row["threshold_rel"] = rel
    return row


def gather_metrics(
    paths: list[str | Path], csv_out: str | Path, md_out: str | Path | None = None
) -> pd.DataFrame:
    """Read metrics JSON files and write one table as CSV (all columns) and Markdown (main columns)."""
    rows = []
    for p in paths:
        m = json.loads(Path(p).read_text())
        row = metrics_row(m)
        row["metrics_file"] = str(p)
        rows.append(row)
    df = pd.DataFrame(rows)
    Path(csv_out).parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(csv_out, index=False)
    if md_out is not None:
        Path(md_out).write_text(markdown_table(df))
    return df


MAIN_COLUMNS = [
    "dataset",
    "scene",
    "speed",
    "dynamic_range",
    "source",
    "sfm_registered_fraction",
    "ate_rmse_relative",
    "sparse_fscore",
    "dense_fscore",
    "mesh_fscore",
    "refined_fscore",
    "image_ssim",
    "image_psnr",
    "textured_psnr",
]


def markdown_table(df: pd.DataFrame, columns: list[str] = MAIN_COLUMNS) -> str:
    """The main columns of the table as GitHub Markdown (numbers to 3 significant digits)."""
    cols = [c for c in columns if c in df.columns]
    if df.empty:
        return "_no runs_\n"
    sub = df[cols].copy()
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in sub.iterrows():
        cells = []
        for c in cols:
            v = r[c]
            if isinstance(v, float):
                cells.append("" if pd.isna(v) else f"{v:.3g}")
            else:
                cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
