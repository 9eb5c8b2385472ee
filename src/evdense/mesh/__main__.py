"""``python -m evdense.mesh {surface,refine,texture} ...``: the mesh stages alone, on a dense
workspace (``results/<dataset>/mvs/<source>/``, holding ``fused.ply``, ``images/``, ``sparse/``)."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser("python -m evdense.mesh", "Mesh, refine or texture from a dense workspace.", "mesh")
    sub = ap.add_subparsers(dest="step", required=True)
    s = sub.add_parser("surface", help="fused.ply -> mesh.ply")
    s.add_argument("workspace")
    s.add_argument("output")
    s.add_argument("--method", default="visibility", help="visibility (default) or poisson")
    r = sub.add_parser("refine", help="mesh.ply -> refined.ply (photometric refinement)")
    r.add_argument("workspace")
    r.add_argument("mesh")
    r.add_argument("output")
    r.add_argument("--threads", type=int, default=None)
    t = sub.add_parser("texture", help="mesh -> textured OBJ + MTL + PNG, PLY, GLB in a folder")
    t.add_argument("workspace")
    t.add_argument("mesh")
    t.add_argument("output_dir")
    args = parse(ap, argv)
    from pathlib import Path

    from evdense.mesh.stage import mesh_surface, refine_mesh, texture_mesh

    conf = config_section(args)
    ws = Path(args.workspace)
    if args.step == "surface":
        mesh_surface(ws / "fused.ply", ws, args.output, args.method, conf)
    elif args.step == "refine":
        refine_mesh(args.mesh, ws, args.output, conf, threads=args.threads)
    else:
        texture_mesh(args.mesh, ws, args.output_dir, conf)


if __name__ == "__main__":
    main()
