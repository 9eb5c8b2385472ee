"""``python -m evdense.evaluate GT_DIR SFM_DIR OUT.json [--frames DIR] [--dense PLY]
[--mesh NAME=PATH ...] [--config evaluate.yaml]``: one image source scored against GT alone."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser("python -m evdense.evaluate", "Score one source's products against GT.", "evaluate")
    ap.add_argument("gt_dir", help="GT folder (mesh.ply, trajectory.txt, intrinsics.yaml, ...)")
    ap.add_argument("sfm_dir", help="SfM folder (trajectory.txt, stats.json, sparse/0)")
    ap.add_argument("out", help="the metrics JSON to write")
    ap.add_argument("--frames", help="the source's frames folder (image scores)")
    ap.add_argument("--dense", help="the fused dense cloud (fused.ply)")
    ap.add_argument("--mesh", action="append", default=[], metavar="NAME=PATH",
                    help="a mesh to score, e.g. refined=.../refined.ply (repeatable)")  # fmt: skip
    args = parse(ap, argv)
    from evdense.evaluate.stage import run_evaluate

    meshes = dict(m.split("=", 1) for m in args.mesh)
    run_evaluate(args.gt_dir, args.sfm_dir, args.out, args.frames, args.dense, meshes,
                    config_section(args))  # fmt: skip


if __name__ == "__main__":
    main()
