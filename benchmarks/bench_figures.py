"""What drawing a run's pictures costs, and what the mesh page shows in a browser (issue 22).

Usage: .venv/bin/python benchmarks/bench_figures.py [--results results] [--dataset room_fast]
           [--summary results/summary] [--out results/bench_figures]

On a finished run (the default run: ``bash quickstart.sh run``) it prints:

- the wall time of each rule that draws (``plot_dataset`` per dataset, ``plot_figures``), as the
  run's own benchmark files recorded them, and their sum: what the pictures add to the run;
- the same pictures drawn again here from the products on disk, timed (one process, imports
  included), with the figure files it made;
- the mesh page (``results/<dataset>/meshes.html``) opened in headless Chromium (Debian's
  ``chromium``): its screenshot (``<out>/meshes_<dataset>.png``) and, per panel, the fraction of
  its canvas that is not the viewer's background, i.e. whether each mesh is on screen.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from evdense.formats.layout import Layout

ROOT = Path(__file__).resolve().parents[1]
BACKGROUND = np.array([31, 31, 36])  # the viewer's clear colour (0.12, 0.12, 0.14)


def rule_seconds(tsv: Path) -> float | None:
    if not tsv.is_file():
        return None
    lines = tsv.read_text().splitlines()
    return float(lines[1].split("\t")[0]) if len(lines) > 1 else None


def sources_of(results: Path, dataset: str) -> dict[str, dict[str, str | None]]:
    """The SourceFiles of every source that has an evaluation (what rule plot_dataset passes)."""
    layout = Layout(str(results))
    out = {}
    for metrics in sorted(Path(layout.stage(dataset, "eval")).glob("*/metrics.json")):
        src = metrics.parent.name
        mesh_root = Path(layout.stage(dataset, "mesh")) / src
        method = next((p.name for p in mesh_root.iterdir() if p.is_dir()), "poisson")
        _, refined, textured = layout.mesh_products(dataset, src, method)
        out[src] = {
            "frames": layout.frames(dataset, src),
            "sfm": layout.sfm(dataset, src),
            "dense": layout.dense_cloud(dataset, src),
            "refined": refined,
            "textured": textured,
            "metrics": str(metrics),
        }
    return out


def screenshot(page: Path, png: Path, panels: int) -> list[float]:
    """Open ``page`` in headless Chromium, save a screenshot, return each panel's covered fraction."""
    import imageio.v3 as iio

    width = 420 * min(panels, 3) + 40
    subprocess.run(
        ["chromium", "--headless", "--no-sandbox", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", f"--window-size={width},600",
         "--virtual-time-budget=15000", f"--screenshot={png}", page.resolve().as_uri()],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    img = iio.imread(png)[..., :3].astype(int)
    canvas_rows = img[90:500]
    covered = []
    col_w = (width - 16) / min(panels, 3)
    for k in range(min(panels, 3)):
        x0, x1 = int(8 + k * col_w + 10), int(8 + (k + 1) * col_w - 10)
        panel = canvas_rows[:, x0:x1]
        covered.append(float((np.abs(panel - BACKGROUND).max(-1) > 8).mean()))
    return covered


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--results", default="results")
    ap.add_argument("--dataset", default="room_fast")
    ap.add_argument("--summary", default="results/summary")
    ap.add_argument("--out", default="results/bench_figures")
    args = ap.parse_args()
    results, out = Path(args.results), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    d = args.dataset

    recorded = {
        f"plot_dataset ({d})": rule_seconds(results / d / "benchmarks" / "plot_dataset.tsv"),
        "plot_figures": rule_seconds(Path(args.summary) / "benchmarks" / "plot_figures.tsv"),
    }
    print("pictures in the run (the rules' own benchmark files):")
    for k, v in recorded.items():
        print(f"  {k:28s} {'-' if v is None else f'{v:6.1f} s'}")
    known = [v for v in recorded.values() if v is not None]
    print(f"  {'total':28s} {sum(known):6.1f} s")

    sources = sources_of(results, d)
    code = (
        "import json, sys, time\n"
        "t0 = time.monotonic()\n"
        "from evdense.evaluate.dataset_figures import SourceFiles, make_dataset_figures\n"
        "a = json.loads(sys.argv[1])\n"
        "made = make_dataset_figures(a['d'], a['out'], {k: SourceFiles.from_dict(v) "
        "for k, v in a['sources'].items()}, a['gt'], a['events'], a['page'])\n"
        "print(json.dumps({'seconds': time.monotonic() - t0, 'files': len(made)}))\n"
    )
    arg = {
        "d": d,
        "out": str(out / d),
        "sources": sources,
        "gt": str(results / d / "gt"),
        "events": str(results / d / "events" / "events.h5"),
        "page": str(out / f"meshes_{d}.html"),
    }
    t0 = time.monotonic()
    run = subprocess.run(
        [sys.executable, "-c", code, json.dumps(arg)], capture_output=True, text=True, check=True
    )
    res = json.loads(run.stdout.strip().splitlines()[-1])
    print(
        f"redrawn here: {res['files']} files for {len(sources)} sources in "
        f"{time.monotonic() - t0:.1f} s (process), {res['seconds']:.1f} s (imports included)"
    )

    page = results / d / "meshes.html"
    page = page if page.is_file() else out / f"meshes_{d}.html"
    if shutil.which("chromium") is None:
        print("chromium not installed (apt-get install chromium): page not checked")
        return 0
    n = json.loads(page.read_text().split('id="evdense-meshes">', 1)[1].split("</script>", 1)[0])[
        "meshes"
    ]
    png = out / f"meshes_{d}.png"
    covered = screenshot(page, png, len(n))
    print(f"mesh page {page} ({page.stat().st_size / 1e6:.1f} MB), {len(n)} meshes: {png}")
    for m, c in zip(n, covered, strict=False):
        print(f"  {m['label']:40s} {m['faces']:8d} faces, {100 * c:5.1f} % of its panel drawn")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
