"""``python -m evdense.refine WORKSPACE MESH OUTPUT [--stats refined.json] [--threads N]
[--config mesh.yaml]``: photometric refinement of a mesh against a dense workspace's images."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser("python -m evdense.refine", "Refine a mesh photometrically.", "mesh")
    ap.add_argument("workspace", help="dense workspace (sparse/, images/)")
    ap.add_argument("mesh", help="the mesh PLY to refine")
    ap.add_argument("output", help="refined mesh PLY to write")
    ap.add_argument("--stats", help="JSON of the photometric scores to write")
    ap.add_argument("--threads", type=int, default=None)
    args = parse(ap, argv)
    from evdense.refine.stage import run_refine

    conf = config_section(args).get("refine", {})
    run_refine(args.mesh, args.workspace, args.output, conf, args.stats, args.threads)


if __name__ == "__main__":
    main()
