"""The command line: what `evdense reconstruct` prints at the end of a run."""

from __future__ import annotations

import json

from evdense.cli import print_products
from evdense.formats.layout import Layout


def test_reconstruct_names_every_product_and_failed_sources(tmp_path, capsys):
    lay = Layout(str(tmp_path / "results"))
    for src, failed in (("conventional", False), ("ours_n25000_b5", True)):
        sfm = tmp_path / lay.sfm("rec", src)
        sfm.mkdir(parents=True)
        (sfm / "stats.json").write_text(json.dumps({"failed": failed}))
    textured = tmp_path / lay.mesh_products("rec", "conventional", "visibility")[2]
    textured.parent.mkdir(parents=True)
    textured.write_text("# obj\n")
    (tmp_path / lay.mesh_page("rec")).write_text("<html></html>")
    print_products(tmp_path / "results", "rec", "rec.aedat4")
    out = capsys.readouterr().out
    assert "conventional: ok" in out and "ours_n25000_b5: SfM failed" in out
    assert str(textured) in out and "meshes page" in out


def test_run_workflow_plans_runs_and_reports_a_failed_job(tmp_path, monkeypatch):
    """Through Snakemake's API: a dry run plans without writing results; a recording that is
    not one fails its ingest job, the call says so, and nothing that looks complete is left."""
    import os

    import numpy as np
    import yaml

    from evdense.workflow import run_workflow

    bad = tmp_path / "bad.aedat4"
    bad.write_bytes(np.random.default_rng(0).bytes(5000))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"datasets": {"bad": {"recording": str(bad)}}}))
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    assert run_workflow(cfg, out, cores=1, dry_run=True)
    assert not (out / "results").exists()
    assert not run_workflow(cfg, out, cores=1)
    assert os.getcwd() == str(tmp_path)
    assert not (out / "results" / "bad" / "events" / "events.h5").exists()
    logged = (out / "results" / "bad" / "logs" / "ingest.log").read_text()
    assert "bad.aedat4: unrecognised recording format" in logged  # the job's log says why
