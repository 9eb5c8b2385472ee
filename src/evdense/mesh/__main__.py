"""``python -m evdense.mesh WORKSPACE OUTPUT [--method visibility|poisson] [--config mesh.yaml]``:
the mesh stage alone, on a dense workspace (``results/<dataset>/mvs/<source>/``, holding
``fused.ply``, ``images/``, ``sparse/``). Refinement and texture: ``python -m evdense.refine``,
``python -m evdense.texture``."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser("python -m evdense.mesh", "Mesh the fused cloud of a dense workspace.", "mesh")
    ap.add_argument("workspace", help="dense workspace (fused.ply, sparse/, images/)")
    ap.add_argument("output", help="mesh PLY to write")
    ap.add_argument("--method", default="visibility", help="visibility (default) or poisson")
    args = parse(ap, argv)
    from pathlib import Path

    from evdense.mesh.stage import run_mesh

    ws = Path(args.workspace)
    run_mesh(ws / "fused.ply", ws, args.output, args.method, config_section(args))


if __name__ == "__main__":
    main()
