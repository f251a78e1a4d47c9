#!/usr/bin/env bash
# The CT head of Debian's invesalius-examples as a Tessera volume: unpacks Cranium.inv3 (a tar.gz
# of InVesalius' project files) and writes a raw-with-sidecar description of its CT matrix
# (cranium.vol.toml), the same data as a detached NRRD header placed as InVesalius places its
# surfaces (cranium.nhdr: y runs negative), and, where Python's vtk is at hand (VTK_PYTHON,
# default the venv deploy/bench/vtk-compare.sh makes), the skull surface InVesalius extracted
# as skull.ply with a scene of both (cranium-skull.scene.toml). Prints the sidecar's path.
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
# Axial slices from the neck up: superior is +z, so the head stands upright.
up = [0.0, 0.0, 1.0]
TOML
cat > "$dir/cranium.nhdr" <<NHDR
NRRD0004
type: short
dimension: 3
sizes: 256 256 108
space dimension: 3
space directions: (0.9570312,0,0) (0,-0.9570312,0) (0,0,1.5)
space origin: (0,0,0)
endian: little
encoding: raw
data file: cranium.raw
NHDR
py=${VTK_PYTHON:-${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench/vtk-venv/bin/python}
surface="$(find "$tmp" -name surface_0.vtp | head -n 1)"
if [ -x "$py" ] && "$py" -c 'import vtk' 2>/dev/null && [ -n "$surface" ]; then
    "$py" - "$surface" "$dir/skull.ply" <<'PY' 2>/dev/null
import sys, vtk
reader = vtk.vtkXMLPolyDataReader()
reader.SetFileName(sys.argv[1])
triangles = vtk.vtkTriangleFilter()
triangles.SetInputConnection(reader.GetOutputPort())
writer = vtk.vtkPLYWriter()
writer.SetFileName(sys.argv[2])
writer.SetInputConnection(triangles.GetOutputPort())
writer.SetFileTypeToBinary()
writer.Write()
PY
    printf 'meshes = ["skull.ply"]\nvolume = "cranium.nhdr"\n' > "$dir/cranium-skull.scene.toml"
else
    echo "fetch-cranium: no Python vtk ($py): skipping skull.ply and the mesh + volume scene" >&2
fi
echo "$dir/cranium.vol.toml"
