"""``python -m evdense.sfm FRAMES_DIR OUT_DIR [--config sfm.yaml] [--threads N]``."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser(
        "python -m evdense.sfm", "Structure from motion on a frames folder with pycolmap.", "sfm"
    )
    ap.add_argument("frames_dir")
    ap.add_argument("out_dir")
    ap.add_argument("--threads", type=int, default=None)
    args = parse(ap, argv)
    from evdense.sfm.stage import run_sfm

    run_sfm(args.frames_dir, args.out_dir, config_section(args), num_threads=args.threads)


if __name__ == "__main__":
    main()
