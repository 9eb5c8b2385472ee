"""``python -m evdense.texture WORKSPACE MESH OUTPUT_DIR [--config mesh.yaml]``: texture a mesh
from a dense workspace's images (OBJ + MTL + PNG, coloured PLY, GLB in OUTPUT_DIR)."""

from __future__ import annotations

from evdense.stage_cli import config_section, parse, parser


def main(argv: list[str] | None = None) -> None:
    ap = parser("python -m evdense.texture", "Texture a mesh from calibrated images.", "mesh")
    ap.add_argument("workspace", help="dense workspace (sparse/, images/)")
    ap.add_argument("mesh", help="the mesh PLY to texture")
    ap.add_argument("output_dir", help="folder to write")
    args = parse(ap, argv)
    from evdense.texture.stage import run_texture

    run_texture(args.mesh, args.workspace, args.output_dir, config_section(args).get("texture", {}))


if __name__ == "__main__":
    main()
