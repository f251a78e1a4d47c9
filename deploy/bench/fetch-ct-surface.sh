#!/usr/bin/env bash
# Makes a scanned surface nobody here modelled: the bone of the CT head from Debian's
# invesalius-examples (deploy/volumes/fetch-cranium.sh), extracted at 400 HU by VTK's flying
# edges (iso-mesh.py) as a binary PLY of 657,174 irregular triangles, into DIR (default
# ${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench/scans), and prints its path:
#
#   deploy/bench/embree-compare.sh --mesh "$(deploy/bench/fetch-ct-surface.sh)"
#
# VTK comes from PyPI into a virtual environment in the cache (as vtk-compare.sh installs it).
# Commits nothing; run it again and it reuses DIR.
set -euo pipefail

root=$(cd "$(dirname "$0")/../.." && pwd)
cache=${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench
dir=${1:-$cache/scans}
mkdir -p "$dir"
out=$dir/cranium-bone.ply
if [[ ! -s $out ]]; then
    # fetch-cranium.sh prints the .vol.toml (which adds the up axis); VTK reads the NRRD beside it.
    volume=$(bash "$root/deploy/volumes/fetch-cranium.sh")
    volume=${volume%.vol.toml}.nhdr
    venv=$cache/vtk-venv
    if [[ ! -x $venv/bin/python ]] || ! "$venv/bin/python" -c 'import vtk' 2>/dev/null; then
        echo "fetch-ct-surface: installing vtk from PyPI into $venv" >&2
        python3 -m venv "$venv"
        timeout 900 "$venv/bin/pip" install -q vtk numpy
    fi
    echo "fetch-ct-surface: extracting the 400 HU surface of $volume" >&2
    triangles=$(timeout 600 "$venv/bin/python" "$root/deploy/bench/iso-mesh.py" "$volume" 400 "$dir/cranium-bone.tmp.ply")
    [[ $triangles -gt 500000 ]] \
        || { echo "fetch-ct-surface: $triangles triangles, expected over 500,000" >&2; exit 1; }
    mv "$dir/cranium-bone.tmp.ply" "$out"
fi
echo "$out"
