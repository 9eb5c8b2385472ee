"""``python -m evdense.mvs SPARSE_DIR FRAMES_DIR OUT_DIR [--config mvs.yaml] [--threads N]``:
the MVS stage alone, on a COLMAP model (e.g. ``results/<dataset>/sfm/<source>/sparse/0``)."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser("python -m evdense.mvs", "PatchMatch stereo and fusion on a COLMAP model.", "mvs")
    ap.add_argument("sparse_dir", help="COLMAP model (cameras, images, points3D)")
    ap.add_argument("frames_dir", help="the frames the model was made from")
    ap.add_argument("out_dir", help="the dense workspace, fused.ply and stats.json")
    ap.add_argument("--threads", type=int, default=None)
    args = parse(ap, argv)
    from evdense.mvs.stage import run_mvs

    run_mvs(args.sparse_dir, args.frames_dir, args.out_dir, config_section(args), args.threads)


if __name__ == "__main__":
    main()
