"""The workflow itself: the tiny config runs every rule down to the report; the SLURM profile
plans the full sweep; a bad config stops Snakemake before anything is written."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile")]


def snakemake(*args: str, cwd: Path, timeout: int = 1200) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*SNAKEMAKE, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def rules_in(workflow_text: str) -> set[str]:
    return set(re.findall(r"^rule (\w+):", workflow_text, flags=re.M))


@pytest.mark.slow
def test_tiny_config_runs_every_rule_down_to_the_report(tmp_path):
    run = snakemake(
        "--cores",
        "2",
        "--configfile",
        str(REPO / "config/test.yaml"),
        "-d",
        str(tmp_path),
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    log = run.stdout + run.stderr
    ran = set(re.findall(r"Finished jobid: \d+ \(Rule: (\w+)\)", log))
    defined = set()
    for smk in (REPO / "workflow" / "rules").glob("*.smk"):
        defined |= rules_in(smk.read_text())
    # Rules for other kinds of input (real recordings, training, the MVS oracle check) are not
    # part of the default chain of a synthetic dataset.
    optional = {"ingest", "train_model", "build_oracle_model", "evaluate_mvs_oracle"}
    assert defined - optional <= ran, f"rules that did not run: {sorted(defined - optional - ran)}"

    res = tmp_path / "results"
    table = pd.read_csv(res / "summary" / "metrics.csv")
    assert set(table["source"]) == {"gt", "conventional", "ours_n2000_b5"}
    gt_row = table[table["source"] == "gt"].iloc[0]
    assert gt_row["sfm_registered_fraction"] == 1.0
    assert gt_row["image_ssim"] > 0.95  # the GT frames against GT radiance
    assert gt_row["ate_rmse_relative"] < 0.05
    metrics = json.loads((res / "tiny" / "eval" / "gt" / "metrics.json").read_text())
    assert metrics["geometry"]["dense"]["num_points"] > 0
    assert (res / "summary" / "summary.md").read_text().startswith("# evdense run summary")
    assert (res / "summary" / "figures").is_dir()  # the run's figures: none, nothing is swept here
    # each dataset's pictures: the paper's figures, the error-coloured views of every source
    figs = {p.name for p in (res / "tiny" / "figures").glob("*.png")}
    assert {"events_spacetime.png", "event_frames.png", "frames.png", "reconstructions.png",
            "prf_vs_threshold.png", "trajectory.png"} <= figs  # fmt: skip
    assert {f"errors_{s}.png" for s in table["source"]} <= figs
    assert all((res / "tiny" / "figures" / f).with_suffix(".pdf").is_file() for f in figs)
    curve = metrics["geometry"]["refined"]["curve"]
    assert len(curve["fscore"]) == len(curve["relative_thresholds"]) > 10
    page = (res / "tiny" / "meshes.html").read_text()
    registered = int((~table["failed"].astype(bool)).sum())  # a source whose SfM failed has no mesh
    assert page.count('"frame":"gt"') == registered >= 2  # the textured meshes, in the GT frame

    report = snakemake(
        "--report", "report.html", "--configfile", str(REPO / "config/test.yaml"), cwd=tmp_path
    )
    assert report.returncode == 0, report.stderr[-3000:]
    assert (tmp_path / "report.html").stat().st_size > 10_000

    # Nothing reruns once everything is made.
    again = snakemake(
        "--cores", "2", "-n", "--configfile", str(REPO / "config/test.yaml"), cwd=tmp_path
    )
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr

    # A texture setting reruns texturing and what reads it, not meshing or refinement.
    overlay = tmp_path / "texture.yaml"
    overlay.write_text("mesh:\n  texture:\n    smoothness: 0.5\n")
    plan = snakemake(
        "-n",
        "--configfile",
        str(REPO / "config/test.yaml"),
        str(overlay),
        cwd=tmp_path,
    )
    planned = set(re.findall(r"^(?:local)?rule (\w+):", plan.stdout + plan.stderr, flags=re.M))
    assert plan.returncode == 0 and "texture_mesh" in planned, plan.stdout[-2000:]
    assert not planned & {"mesh_surface", "refine_mesh", "run_mvs"}


def test_slurm_profile_plans_the_full_sweep(tmp_path):
    pytest.importorskip("snakemake_executor_plugin_slurm")
    run = snakemake(
        "-n",
        "--workflow-profile",
        str(REPO / "workflow/profiles/slurm"),
        "--configfile",
        str(REPO / "config/experiment.yaml"),
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    out = run.stdout + run.stderr
    total = int(re.search(r"^total\s+(\d+)", out, flags=re.M).group(1))
    sims = int(re.search(r"^simulate_events\s+(\d+)", out, flags=re.M).group(1))
    assert sims == 18  # 3 scenes x (4 speeds + 3 dynamic ranges - the shared speed 1 / range 1)
    assert (
        int(re.search(r"^run_sfm\s+(\d+)", out, flags=re.M).group(1)) == 18 * 3
    )  # events, conventional, gt
    assert total > 150
    # the sweep's table has its own place: it does not overwrite the default run's
    assert "results/summary_experiment/metrics.csv" in out
    assert "results/summary/metrics.csv" not in out
    assert not (tmp_path / "results").exists()


@pytest.mark.parametrize(
    ("dataset", "key"),
    [
        ({"scene": "room", "speed": 0}, "datasets.bad.speed"),
        ({"scene": "no_such_preset"}, "datasets.bad"),
        ({"scene": "room", "recording": "x.aedat4"}, "datasets.bad"),
    ],
)
def test_bad_config_names_the_key_and_writes_nothing(tmp_path, dataset, key):
    import yaml

    cfg = tmp_path / "bad.yaml"
    cfg.write_text(yaml.safe_dump({"datasets": {"bad": dataset}}))
    run = snakemake("-n", "--configfile", str(cfg), cwd=tmp_path)
    assert run.returncode != 0
    assert key in run.stdout + run.stderr
    assert not (tmp_path / "results").exists()


@pytest.mark.slow
def test_real_recording_runs_to_the_end(tmp_path, anchors):
    """The Event Camera Dataset's slider_depth as a user gives it: its APS frames register with
    the calibration that ships with it (fixed), reach a textured mesh and are measured against the
    mocap; its event source (50,000 events, 0.17 s) ends as a recorded SfM failure that says why,
    or registers; the run finishes either way."""
    rec = anchors / "data" / "ecd_slider_depth"
    conf = tmp_path / "config.yaml"
    conf.write_text(
        f"datasets:\n  slider:\n    recording: {rec}\n"
        "events:\n  window:\n    num_events: 10000\n"
        "sfm:\n  select_count: 24\n"
        "mvs:\n  max_image_size: 160\n"
        "mesh:\n  refine:\n    iterations: 5\n"
    )
    run = snakemake("--cores", "2", "--configfile", str(conf), "-d", str(tmp_path), cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    res = tmp_path / "results" / "slider"
    aps = json.loads((res / "sfm" / "conventional" / "stats.json").read_text())
    assert aps["num_registered"] == aps["num_selected"] == 24
    assert aps["intrinsics_source"].endswith("gt/intrinsics.yaml")  # the shipped calibration
    assert aps["camera"]["focal_length_x"] == pytest.approx(335.419, abs=0.01)
    assert (res / "mesh" / "conventional" / "visibility" / "textured" / "mesh.obj").stat().st_size
    m = json.loads((res / "eval" / "conventional" / "metrics.json").read_text())
    assert m["trajectory"]["ate_rmse_relative"] < 0.01
    ev = json.loads((res / "eval" / "ours_n10000_b5" / "metrics.json").read_text())
    assert ev["images"]["reference"] == "aps_nearest" and ev["images"]["num_frames"] > 0
    ev_sfm = json.loads((res / "sfm" / "ours_n10000_b5" / "stats.json").read_text())
    if ev_sfm.get("failed"):
        assert "registered" in ev_sfm["error"]
    table = pd.read_csv(tmp_path / "results" / "summary" / "metrics.csv")
    assert set(table["source"]) == {"conventional", "ours_n10000_b5"}
    # its pictures: in the mocap's frame (GT poses, no GT surface, so no error views)
    figs = {p.name for p in (res / "figures").glob("*.png")}
    assert {"trajectory.png", "reconstructions.png", "frames.png", "event_frames.png"} <= figs
    assert '"frame":"gt"' in (res / "meshes.html").read_text()
