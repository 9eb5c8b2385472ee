"""``python -m evdense.recon VOXELS OUT_DIR [--preset ours] [--events EVENTS.h5]
[--conventional FRAMES_DIR] [--threads N] [--config config.yaml]``: one preset's frames from a
voxel file alone (the workflow's ``reconstruct_frames`` rule)."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser(
        "python -m evdense.recon", "Frames from a voxel file with one preset.", "reconstruct"
    )
    ap.add_argument("voxels", help="voxel file (results/<dataset>/events/voxels_<spec>_b5.h5)")
    ap.add_argument("out_dir", help="frames folder to write (PNGs + timestamps.txt)")
    ap.add_argument(
        "--preset", default="ours", help="a reconstruct preset or method (default ours)"
    )
    ap.add_argument("--events", help="canonical event file (the classical baselines need it)")
    ap.add_argument("--conventional", help="conventional frames folder (complementary filter)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads")
    args = parse(ap, argv)
    from evdense.config import fill_section
    from evdense.recon.config import resolve_config
    from evdense.recon.stage import run_recon

    conf = resolve_config(fill_section("reconstruct", config_section(args)), args.preset)
    run_recon(args.voxels, args.out_dir, conf, args.events, args.conventional, args.threads)


if __name__ == "__main__":
    main()
