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
