"""Figures of a finished run, per dataset and image source: SfM, MVS, mesh, texture, time per stage.

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_pipeline.py [--results results]
           [--datasets room_fast ...] [--threshold 0.01]

Reads what the workflow wrote (``results/<dataset>/eval/<source>/metrics.json``,
``results/<dataset>/sfm/<source>/stats.json``, ``results/<dataset>/benchmarks/**.tsv``) after
``snakemake --cores 2 [--configfile ...]`` and prints, per dataset:

- SfM: frames given / selected, registered fraction, mean reprojection error (px), focal length
  against GT, camera-centre RMSE after Sim(3) as a fraction of the trajectory length (issue 5);
- geometry: precision / recall / F-score of the sparse cloud, dense cloud, mesh and refined mesh at
  ``--threshold`` (a fraction of the GT bounding-box diagonal; completeness on the GT surface the
  GT cameras observed), and at 0.5 % for the dense cloud (the MVS figure of issue 6);
- the textured mesh rendered from held-out GT cameras: PSNR / SSIM / coverage (issue 7);
- wall time of each rule from Snakemake's benchmark files, and their sum (issue 8).
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def at(geom: dict, key: str, rel: float) -> float:
    for r, v in zip(geom["relative_thresholds"], geom[key], strict=True):
        if abs(r - rel) < 1e-12:
            return v
    return float("nan")


def rule_times(ds_dir: Path) -> dict[str, float]:
    """Seconds per benchmark file (``rule`` or ``rule/wildcards``) of one dataset."""
    out = {}
    for tsv in sorted((ds_dir / "benchmarks").rglob("*.tsv")):
        with tsv.open() as f:
            rows = list(csv.DictReader(f, delimiter="\t"))
        if rows:
            out[str(tsv.relative_to(ds_dir / "benchmarks").with_suffix(""))] = float(rows[-1]["s"])
    return out


def prf(g: dict, key: str, rel: float) -> str:
    """Precision/recall/F-score of product ``key`` at ``rel``, or "-" when it was not made."""
    if key not in g:
        return "-"
    return "/".join(fmt(at(g[key], k, rel), ".2f") for k in ("precision", "recall", "fscore"))


def fmt(v: float, spec: str = ".3f") -> str:
    return "-" if v is None or v != v else format(v, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default=str(ROOT / "results"))
    ap.add_argument("--datasets", nargs="*", help="default: every dataset with metrics")
    ap.add_argument("--threshold", type=float, default=0.01)
    args = ap.parse_args()
    results = Path(args.results)
    names = args.datasets or sorted(p.parent.parent.name for p in results.glob("*/eval/*"))
    for name in dict.fromkeys(names):
        ds = results / name
        metrics = sorted((ds / "eval").glob("*/metrics.json"))
        if not metrics:
            continue
        gt_f = None
        intr = ds / "gt" / "intrinsics.yaml"
        if intr.exists():
            from evdense.camera import load_camera

            gt_f = load_camera(intr).fx
        print(f"\n## {name}\n")
        print(
            "| source | frames | selected | registered | reproj px | focal vs GT | centres / length "
            "| sparse P/R/F | dense P/R/F | dense F@0.5% | mesh F | refined F | textured PSNR / SSIM / cover |"
        )
        print("|---" * 13 + "|")
        for path in metrics:
            src = path.parent.name
            m = json.loads(path.read_text())
            sfm = m.get("sfm") or {}
            stats_path = ds / "sfm" / src / "stats.json"
            stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
            focal = (stats.get("camera") or {}).get("focal_length")
            fdev = f"{100 * (focal / gt_f - 1):+.2f} %" if focal and gt_f else "-"
            traj = m.get("trajectory") or {}
            g = m.get("geometry") or {}
            rel = args.threshold

            tex = m.get("textured_renders") or {}
            print(
                f"| {src} | {sfm.get('num_frames', '-')} | {sfm.get('num_selected', '-')} "
                f"| {fmt(sfm.get('registered_fraction'))} | {fmt(sfm.get('mean_reprojection_error_px'))} "
                f"| {fdev} | {fmt(traj.get('ate_rmse_relative'), '.4%')} | {prf(g, 'sparse', rel)} | {prf(g, 'dense', rel)} "
                f"| {fmt(at(g['dense'], 'fscore', 0.005)) if 'dense' in g else '-'} "
                f"| {fmt(at(g['mesh'], 'fscore', rel)) if 'mesh' in g else '-'} "
                f"| {fmt(at(g['refined'], 'fscore', rel)) if 'refined' in g else '-'} "
                f"| {fmt(tex.get('psnr'), '.1f')} / {fmt(tex.get('ssim'), '.2f')} / {fmt(tex.get('coverage'), '.2f')} |"
                + (" SfM failed" if m.get("failed") else "")
            )
        times = rule_times(ds)
        if times:
            total = sum(times.values())
            print(f"\nrule wall times (s), {total:.0f} s in all (jobs may have overlapped):")
            for k, v in times.items():
                print(f"  {k:<55} {v:8.1f}")


if __name__ == "__main__":
    main()
