#!/usr/bin/env bash
# The CT head of Debian's invesalius-examples as a Tessera volume: unpacks Cranium.inv3 (a tar.gz
# of InVesalius' project files) and writes a raw-with-sidecar description of its CT matrix.
#
#   deploy/volumes/fetch-cranium.sh [DIR]    (default ~/.cache/tessera-volumes/cranium)
#
# The matrix is int16 Hounsfield units (-1024..3033), 256 x 256 x 108 voxels, x fastest, spacing
# 0.957 x 0.957 x 1.5 mm, as main.plist in the archive says; the script checks the byte count.
# Installs the package when run as root and it is missing.
set -euo pipefail
dir="${1:-$HOME/.cache/tessera-volumes/cranium}"
inv=/usr/share/doc/invesalius-examples/examples/Cranium.inv3
if [ ! -f "$inv" ]; then
    if [ "$(id -u)" = 0 ]; then
        apt-get install -y --no-install-recommends invesalius-examples >/dev/null ||
            { apt-get update >/dev/null && apt-get install -y --no-install-recommends invesalius-examples >/dev/null; }
    else
        echo "fetch-cranium: $inv is missing; as root: apt-get install invesalius-examples" >&2
        exit 1
    fi
fi
mkdir -p "$dir"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
tar -xzf "$inv" -C "$tmp"
matrix="$(find "$tmp" -name matrix.dat | head -n 1)"
plist="$(dirname "$matrix")/main.plist"
grep -q '<string>int16</string>' "$plist" || { echo "fetch-cranium: the matrix is not int16" >&2; exit 1; }
size=$(stat -c %s "$matrix")
if [ "$size" != $((256 * 256 * 108 * 2)) ]; then
    echo "fetch-cranium: matrix.dat has $size bytes, not 256x256x108 int16" >&2
    exit 1
fi
mv "$matrix" "$dir/cranium.raw"
cat > "$dir/cranium.vol.toml" <<TOML
# The CT head of invesalius-examples (ProMED CT 0051), Hounsfield units.
data = "cranium.raw"
dims = [256, 256, 108]
type = "i16"
spacing = [0.9570312, 0.9570312, 1.5]
endian = "little"
TOML
echo "$dir/cranium.vol.toml"
