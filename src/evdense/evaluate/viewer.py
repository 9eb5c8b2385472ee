"""A self-contained HTML page that shows textured meshes side by side in a 3D viewer.

The page needs nothing but a browser with WebGL: the viewer (``viewer.js``, ours, plain WebGL)
and every mesh (corner positions and texture coordinates as base64 float32, the atlas as a PNG
data URI) are written into the file, and nothing is fetched when it opens. Meshes that share a
frame (say, all reconstructions aligned to the GT frame) share one camera: turning one turns all.
"""

from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from evdense.formats.files import write_text_atomic
from evdense.log import get_logger
from evdense.texture import TexturedMesh

log = get_logger("viewer")


@dataclass
class PageView:
    """The start view of a frame's camera: OpenCV-style pose ``T_wc`` (x right, y down, z ahead)
    turned into eye, target and up, and the vertical field of view."""

    eye: list[float]
    target: list[float]
    up: list[float]
    fov_y_deg: float
    scale: float
    """A length of the scene (sets the clipping planes)."""

    @classmethod
    def from_pose(
        cls, T_wc: np.ndarray, fov_y_deg: float, distance: float, scale: float
    ) -> PageView:
        """Looking along the pose's optical axis at a target ``distance`` ahead."""
        T = np.asarray(T_wc, dtype=np.float64)
        eye = T[:3, 3]
        return cls(
            eye=eye.tolist(),
            target=(eye + distance * T[:3, 2]).tolist(),
            up=(-T[:3, 1]).tolist(),
            fov_y_deg=float(fov_y_deg),
            scale=float(scale),
        )


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a, dtype="<f4").tobytes()).decode("ascii")


def _png_data_uri(atlas: np.ndarray) -> str:
    import imageio.v3 as iio

    img = np.clip(np.rint(atlas * 255), 0, 255).astype(np.uint8)
    png = iio.imwrite("<bytes>", img[..., 0] if img.shape[2] == 1 else img, extension=".png")
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def mesh_entry(tm: TexturedMesh, label: str, frame: str = "world") -> dict:
    """One mesh of the page: its corners (unshared, as the atlas needs), atlas and label."""
    return {
        "label": label,
        "frame": frame,
        "positions": _b64(tm.vertices[tm.faces].reshape(-1, 3)),
        "uvs": _b64(tm.face_uvs.reshape(-1, 2)),
        "texture": _png_data_uri(tm.atlas),
        "faces": len(tm.faces),
    }


def write_mesh_page(
    out_html: str | Path,
    meshes: list[dict],
    views: dict[str, PageView],
    title: str = "evdense meshes",
    notes: str = "",
) -> Path:
    """Write the page: ``meshes`` from :func:`mesh_entry` (each names its frame), ``views`` the
    start view of each frame."""
    missing = {m["frame"] for m in meshes} - set(views)
    if missing:
        raise ValueError(f"write_mesh_page: no start view for frame(s) {sorted(missing)}")
    script = resources.files("evdense.evaluate").joinpath("viewer.js").read_text()
    payload = {"meshes": meshes, "views": {k: vars(v) for k, v in views.items()}}
    data = json.dumps(payload, separators=(",", ":")).replace("</", "<\\/")
    n = max(1, len(meshes))
    cols = min(n, 3)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>{html.escape(title)}</title>
<style>
body {{ margin: 0; font: 14px system-ui, sans-serif; background: #f4f4f4; color: #222; }}
header {{ padding: 8px 14px; }} header h1 {{ font-size: 17px; margin: 4px 0; }}
#evdense-grid {{ display: grid; grid-template-columns: repeat({cols}, 1fr); gap: 8px; padding: 0 8px 8px; }}
figure {{ margin: 0; background: #fff; border: 1px solid #ccc; }}
canvas {{ display: block; width: 100%; height: 420px; cursor: grab; }}
figcaption {{ padding: 4px 8px; font-size: 13px; }}
</style></head>
<body>
<header><h1>{html.escape(title)}</h1>
<div>{html.escape(notes)} Drag to turn, shift-drag to pan, wheel to zoom, double-click to reset;
panels in one frame turn together.</div></header>
<div id="evdense-grid"></div>
<script type="application/json" id="evdense-meshes">{data}</script>
<script>
{script}
</script>
</body></html>
"""
    out_html = Path(out_html)
    out_html.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out_html, page)
    log.info(
        "%s: %d meshes, %d faces, %.1f MB",
        out_html, len(meshes), sum(m["faces"] for m in meshes), len(page) / 1e6,
    )  # fmt: skip
    return out_html
