#!/usr/bin/env bash
# A larger pool of pictures for the planar training generator (train.data.picture_dirs), made from
# two Debian packages fetched from the package registry (nothing is installed):
#   openarena-081-textures  1,231 JPEG surface textures (walls, floors, metal, stone, wood; GPL-2)
#   mate-backgrounds        about 30 desktop backgrounds, a dozen of them photographs (GPL-2+)
# Usage: benchmarks/make_picture_pool.sh [OUT]   (default results/pictures; idempotent: a pool
# already complete is left as it is). Pass OUT/openarena and OUT/mate as train.data.picture_dirs.
# OUT/.complete names the package versions; counts differ with other versions.
set -euo pipefail
out=${1:-results/pictures}
if [ -f "$out/.complete" ]; then
    echo "picture pool: $out already made ($(find "$out" -type f \( -iname '*.jpg' -o -iname '*.png' \) | wc -l) images)"
    exit 0
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && apt-get download openarena-081-textures mate-backgrounds >/dev/null)
for deb in "$work"/*.deb; do dpkg-deb -x "$deb" "$work/x"; done
part="$out.partial" # built aside, moved into place only when whole
rm -rf "$part"
mkdir -p "$part/openarena" "$part/mate"
python3 - "$work/x" "$part" <<'PY'
import sys, zipfile
from pathlib import Path

x, out = Path(sys.argv[1]), Path(sys.argv[2])
(pk3,) = x.glob("usr/share/games/openarena/baseoa/pak*-textures.pk3")
with zipfile.ZipFile(pk3) as z:
    for name in z.namelist():
        if name.lower().endswith(".jpg"):
            (out / "openarena" / name.replace("/", "__")).write_bytes(z.read(name))
for f in sorted((x / "usr/share/backgrounds/mate").rglob("*")):
    if f.suffix.lower() in (".jpg", ".png"):
        (out / "mate" / f"{f.parent.name}__{f.name}").write_bytes(f.read_bytes())
for sub in ("openarena", "mate"):
    if not any((out / sub).iterdir()):
        sys.exit(f"picture pool: no picture found for {sub} in its package")
PY
cp "$work"/x/usr/share/doc/openarena-081-textures/copyright "$part/openarena/COPYRIGHT"
cp "$work"/x/usr/share/doc/mate-backgrounds/copyright "$part/mate/COPYRIGHT"
for deb in "$work"/*.deb; do dpkg-deb -f "$deb" Package Version | paste -sd' '; done >"$part/.complete"
rm -rf "$out"
mv "$part" "$out"
echo "picture pool: $out ($(find "$out" -type f \( -iname '*.jpg' -o -iname '*.png' \) | wc -l) images: $(paste -sd';' "$out/.complete"))"
