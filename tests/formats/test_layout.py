"""The results layout: one spelling for the workflow and the Python code."""

from __future__ import annotations

from evdense.formats.layout import Layout


def test_layout_spells_products_and_snakemake_patterns():
    lay = Layout("results")
    assert lay.frames("room", "ours_n25000_b5") == "results/room/frames/ours_n25000_b5"
    assert lay.frames("room", "gt") == lay.frames("room", "oracle") == "results/room/gt/frames"
    assert lay.source_images("room", "conventional") == "results/room/conventional"
    assert lay.frames("room", "conventional") == "results/room/conventional/frames"
    assert lay.mesh_products("room", "gt", "poisson") == (
        "results/room/mesh/gt/poisson/mesh.ply",
        "results/room/mesh/gt/poisson/refined.ply",
        "results/room/mesh/gt/poisson/textured/mesh.obj",
    )
    # with wildcards it gives the rules' patterns
    assert lay.sfm("{dataset}", "{source}") == "results/{dataset}/sfm/{source}"
    assert lay.metrics("{dataset}", "{source}") == "results/{dataset}/eval/{source}/metrics.json"
    assert Layout("/tmp/out/results").dense_cloud("d", "s") == "/tmp/out/results/d/mvs/s/fused.ply"
