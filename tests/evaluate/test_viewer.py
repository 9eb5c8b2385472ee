"""The page of textured meshes: self-contained, and showing the meshes in a real browser."""

from __future__ import annotations

import re
import shutil
import subprocess

import imageio.v3 as iio
import numpy as np
import open3d as o3d
import pytest

from evdense.evaluate.viewer import PageView, mesh_entry, write_mesh_page
from evdense.poses import look_at
from evdense.texture import TexturedMesh


def _checker_box() -> TexturedMesh:
    box = o3d.geometry.TriangleMesh.create_box(1.0, 1.0, 1.0)
    faces = np.asarray(box.triangles).astype(np.int64)
    uv = np.zeros((len(faces), 3, 2))
    uv[:] = [[0, 0], [1, 0], [0, 1]]
    yy, xx = np.mgrid[:64, :64]
    atlas = (((yy // 8 + xx // 8) % 2) * 0.8 + 0.1)[..., None].astype(np.float32)
    return TexturedMesh(np.asarray(box.vertices), faces, uv, atlas)


def _page(tmp_path):
    tm = _checker_box()
    T = look_at(np.array([3.0, -2.5, 2.0]), np.array([0.5, 0.5, 0.5]))
    view = PageView.from_pose(T, 50.0, 3.5, 2.0)
    meshes = [mesh_entry(tm, "a"), mesh_entry(tm, "b"), mesh_entry(tm, "c", frame="own")]
    return write_mesh_page(tmp_path / "meshes.html", meshes, {"world": view, "own": view})


def test_mesh_page_fetches_nothing(tmp_path):
    text = _page(tmp_path).read_text()
    assert "evdense-meshes" in text and "data:image/png;base64," in text
    assert not re.search(r"(src|href)\s*=\s*[\"']?(https?:)?//", text)
    assert "fetch(" not in text and "XMLHttpRequest" not in text and "import " not in text
    with pytest.raises(ValueError, match="no start view"):
        write_mesh_page(tmp_path / "x.html", [mesh_entry(_checker_box(), "a", "nowhere")], {})


@pytest.mark.skipif(shutil.which("chromium") is None, reason="Debian's chromium is not installed")
def test_mesh_page_shows_every_mesh_in_headless_chromium(tmp_path):
    page = _page(tmp_path)
    shot = tmp_path / "shot.png"
    subprocess.run(
        ["chromium", "--headless", "--no-sandbox", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--window-size=1200,560", "--virtual-time-budget=5000",
         f"--screenshot={shot}", page.as_uri()],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    img = iio.imread(shot)[..., :3].astype(int)
    band = img[120:480]  # the canvases, below the heading
    for k in range(3):  # three panels side by side, each shows the checker box
        panel = band[:, 20 + 400 * k : 380 + 400 * k]
        grey = panel.mean(-1)
        assert (grey > 200).mean() > 0.02 and (grey < 60).mean() > 0.02, f"panel {k} is empty"
        bg = np.all(np.abs(panel - [31, 31, 36]) < 6, axis=-1)  # the viewer's clear colour
        assert bg.mean() > 0.3
