#!/usr/bin/env bash
# Primary-ray throughput of a Tessera render node next to Embree 3's `viewer` (Debian 12).
#
#   deploy/bench/embree-compare.sh [--size 1920x1080] [--threads N] [--mesh FILE|knot:S:T]...
#                                  [--frames K] [--fov DEG] [--cache DIR] [--out DIR]
#
# Same triangles, camera, image size and thread count for both; see deploy/bench/README.md.
# Options:
#   --size WxH         image size (default 1920x1080)
#   --threads N        threads for the head-to-head row (default: nproc)
#   --mesh M           an .obj/.ply path or knot:SEGMENTS:SIDES; repeatable (default: the
#                      assimp-testmodels bull, the glmark2 Stanford bunny, knot:2048:1024)
#   --frames K         timed frames per run (default 10); Embree also renders 2 untimed warm-up
#   --fov DEG          vertical field of view of the whole image (default 40)
#   --view-dir X,Y,Z   direction from the mesh centre to the eye (default 0.55,0.45,0.8)
#   --up X,Y,Z         camera up (default 0,1,0)
#   --cache DIR        exported meshes (default ${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench)
#   --out DIR          logs, images, results.tsv, commands.txt (default CACHE/runs/DATE)
#   --timeout S        limit for each benchmark or export command (default 1200)
#   --no-scaling       skip the 1-thread/2-thread runs
#   --reference        also render Tessera's reference image (tessera-master render) per mesh
set -euo pipefail

die() { echo "embree-compare: error: $*" >&2; exit 1; }
note() { echo "embree-compare: $*" >&2; }

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$SCRIPT_DIR/../.." && pwd)
[[ -f $ROOT/Cargo.toml && -d $ROOT/render-node ]] || die "repository root not found at $ROOT"

SIZE=1920x1080
THREADS=$(nproc)
FRAMES=10
FOV=40
VIEW_DIR=0.55,0.45,0.8
UP=0,1,0
CACHE=${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench
OUT=
LIMIT=1200
SCALING=1
REFERENCE=0
MESHES=()
DEFAULT_MESHES=(
    /usr/share/assimp/models/OBJ/WusonOBJ.obj  # assimp-testmodels: 3,732 triangles
    /usr/share/glmark2/models/bunny.obj        # glmark2-data: Stanford bunny, 69,666 triangles
    knot:2048:1024                             # procedural: 4,194,816 triangles
)

need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value"; }
while [[ $# -gt 0 ]]; do
    case $1 in
        --size) need_arg "$@"; SIZE=$2; shift 2 ;;
        --threads) need_arg "$@"; THREADS=$2; shift 2 ;;
        --mesh) need_arg "$@"; MESHES+=("$2"); shift 2 ;;
        --frames) need_arg "$@"; FRAMES=$2; shift 2 ;;
        --fov) need_arg "$@"; FOV=$2; shift 2 ;;
        --view-dir) need_arg "$@"; VIEW_DIR=$2; shift 2 ;;
        --up) need_arg "$@"; UP=$2; shift 2 ;;
        --cache) need_arg "$@"; CACHE=$2; shift 2 ;;
        --out) need_arg "$@"; OUT=$2; shift 2 ;;
        --timeout) need_arg "$@"; LIMIT=$2; shift 2 ;;
        --no-scaling) SCALING=0; shift ;;
        --reference) REFERENCE=1; shift ;;
        -h|--help) sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$0"; exit 0 ;;
        *) die "unknown argument: $1 (see --help)" ;;
    esac
done
[[ $SIZE =~ ^([1-9][0-9]*)x([1-9][0-9]*)$ ]] || die "--size must be WxH, got $SIZE"
WIDTH=${BASH_REMATCH[1]} HEIGHT=${BASH_REMATCH[2]}
[[ $THREADS =~ ^[1-9][0-9]*$ ]] || die "--threads must be a positive integer, got $THREADS"
[[ $FRAMES =~ ^[1-9][0-9]*$ ]] || die "--frames must be a positive integer, got $FRAMES"
[[ $LIMIT =~ ^[1-9][0-9]*$ ]] || die "--timeout must be a positive integer, got $LIMIT"
[[ $FOV =~ ^[0-9]+([.][0-9]+)?$ ]] || die "--fov must be a number of degrees, got $FOV"
vec_re='^-?[0-9.]+(e-?[0-9]+)?,-?[0-9.]+(e-?[0-9]+)?,-?[0-9.]+(e-?[0-9]+)?$'
[[ $VIEW_DIR =~ $vec_re ]] || die "--view-dir must be X,Y,Z, got $VIEW_DIR"
[[ $UP =~ $vec_re ]] || die "--up must be X,Y,Z, got $UP"
[[ ${#MESHES[@]} -gt 0 ]] || MESHES=("${DEFAULT_MESHES[@]}")
command -v python3 >/dev/null || die "python3 is needed (camera and bounds)"
command -v timeout >/dev/null || die "timeout (coreutils) is needed"

OUT=${OUT:-$CACHE/runs/$(date +%Y%m%d-%H%M%S)}
mkdir -p "$CACHE/meshes" "$OUT" || die "cannot create $CACHE/meshes or $OUT"
CMDS=$OUT/commands.txt
: >"$CMDS"

# run LOG LIMIT CMD... : print and record the command, run it under timeout with its output in
# LOG, and stop with the log's tail if it fails or runs out of time.
run() {
    local log=$1 limit=$2
    shift 2
    local line="timeout -k 10 $limit" arg
    for arg in "$@"; do
        if [[ $arg =~ ^[A-Za-z0-9_./:=,@+-]+$ ]]; then line+=" $arg"; else line+=" $(printf '%q' "$arg")"; fi
    done
    echo "+ $line" | tee -a "$CMDS" >&2
    local rc=0
    timeout -k 10 "$limit" "$@" >"$log" 2>&1 || rc=$?
    if [[ $rc -ne 0 ]]; then
        tail -n 25 "$log" >&2
        if [[ $rc -eq 124 || $rc -eq 137 ]]; then
            die "timed out after ${limit}s: $1 (full log: $log)"
        fi
        die "exit status $rc from: $1 (full log: $log)"
    fi
}

# --- 1. Debian packages ---------------------------------------------------------------------
PACKAGES=(embree-tools)
for mesh in "${MESHES[@]}"; do
    case $mesh in
        /usr/share/assimp/*) PACKAGES+=(assimp-testmodels) ;;
        /usr/share/glmark2/*) PACKAGES+=(glmark2-data) ;;
    esac
done
MISSING=()
for pkg in $(printf '%s\n' "${PACKAGES[@]}" | sort -u); do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" \
        || MISSING+=("$pkg")
done
if [[ ${#MISSING[@]} -gt 0 ]]; then
    [[ $(id -u) -eq 0 ]] || die "missing Debian packages: ${MISSING[*]}; install them as root:" \
        "apt-get update && apt-get install -y ${MISSING[*]}"
    command -v apt-get >/dev/null || die "apt-get not found (this script targets Debian 12)"
    export DEBIAN_FRONTEND=noninteractive
    run "$OUT/apt-update.log" 600 apt-get update
    run "$OUT/apt-install.log" 1200 apt-get install -y --no-install-recommends "${MISSING[@]}"
fi
VIEWER=/usr/bin/viewer
[[ -x $VIEWER ]] || die "$VIEWER (package embree-tools) not found"
for mesh in "${MESHES[@]}"; do
    [[ $mesh =~ ^knot:[0-9]+:[0-9]+$ ]] && continue
    [[ -f $mesh ]] || die "mesh $mesh not found"
    case ${mesh,,} in *.obj|*.ply) ;; *) die "mesh $mesh: expected .obj, .ply or knot:S:T" ;; esac
done

# --- 2. Our binaries --------------------------------------------------------------------------
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
[[ $TARGET = /* ]] || TARGET=$ROOT/$TARGET
NODE=$TARGET/release/tessera-render-node
MASTER=$TARGET/release/tessera-master
has_bench() { "$NODE" bench --help >/dev/null 2>&1 && "$NODE" export-obj --help >/dev/null 2>&1; }
if [[ ! -x $NODE || ! -x $MASTER ]] || ! has_bench; then
    command -v cargo >/dev/null || die "cargo not found; cannot build $NODE"
    note "building release binaries (log: $OUT/cargo-build.log)"
    run "$OUT/cargo-build.log" 3600 \
        cargo build --release --manifest-path "$ROOT/Cargo.toml" \
        -p tessera-render-node -p tessera-master
    has_bench || die "$NODE has no 'bench' or 'export-obj' subcommand"
fi

# --- 3. Machine state -------------------------------------------------------------------------
read -r LOAD1 _ </proc/loadavg
CPU=$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -n 1)
note "machine: $(nproc) cpus ($CPU), load average $LOAD1"
if awk -v l="$LOAD1" 'BEGIN { exit !(l > 0.5) }'; then
    note "warning: load average $LOAD1 > 0.5 — something else is running; figures will be low"
fi

# --- 4. Per mesh -------------------------------------------------------------------------------
RESULTS=$OUT/results.tsv
printf 'mesh\ttriangles\tsize\tthreads\tembree_mrayps\ttessera_mrayps\tratio\ttessera_shadow_mrayps\ttessera_ao_mrayps\n' >"$RESULTS"
SCALE=$OUT/scaling.tsv
printf 'mesh\ttessera_1t\ttessera_2t\ttessera_2t_over_1t\tembree_1t\tembree_2t\tembree_2t_over_1t\n' >"$SCALE"

key_of() {  # file name in the cache for a mesh spec
    local spec=$1
    if [[ $spec =~ ^knot:([0-9]+):([0-9]+)$ ]]; then
        echo "knot-${BASH_REMATCH[1]}x${BASH_REMATCH[2]}"
    else
        local abs base
        abs=$(readlink -f -- "$spec")
        base=$(basename -- "$spec")
        echo "${base%.*}-$(printf '%s' "$abs" | sha1sum | cut -c1-8)"
    fi
}

figure() {  # figure NAME LOG: the value on the line "NAME value"
    local v
    v=$(awk -v n="$1" '$1 == n { v = $2 } END { print v }' "$2")
    [[ $v =~ ^[0-9]+([.][0-9]*)?([eE][-+]?[0-9]+)?$ ]] || die "no $1 figure in $2"
    echo "$v"
}

ratio() { awk -v a="$1" -v b="$2" 'BEGIN { if (b > 0) printf "%.3f", a / b; else print "n/a" }'; }

embree_run() {  # embree_run TAG THREADS -> prints Mrays/s
    local tag=$1 threads=$2 log=$OUT/$KEY-embree-$1.log
    run "$log" "$LIMIT" "$VIEWER" -i "$OBJ" -o "$OUT/$KEY-embree-$tag.ppm" \
        --size "$WIDTH" "$HEIGHT" --vp $EYE_S --vi $TARGET_S --vu $UP_S --fov "$CAM_FOV" \
        --threads "$threads" --verbose 1 --benchmark 2 "$FRAMES" --legacy
    local loaded
    loaded=$(awk -F: '/# triangles/ { gsub(/ /, "", $2); v = $2 } END { print v }' "$log")
    [[ $loaded == "$TRIS" ]] || die "Embree loaded ${loaded:-no} triangles from $OBJ, expected $TRIS"
    figure BENCHMARK_RENDER_MRAYPS_AVG "$log"
}

tessera_run() {  # tessera_run TAG THREADS -> sets T_PRIMARY T_SHADOW T_AO
    local tag=$1 threads=$2 log=$OUT/$KEY-tessera-$1.log
    run "$log" "$LIMIT" "$NODE" bench --scene "$OBJ" --size "${WIDTH}x${HEIGHT}" \
        --threads "$threads" --eye="$EYE" --target="$TARGET_P" --up="$CAM_UP" --fov "$CAM_FOV" \
        --frames "$FRAMES"
    T_PRIMARY=$(figure TESSERA_PRIMARY_MRAYPS "$log")
    T_SHADOW=$(awk '$1 == "TESSERA_SHADOW_MRAYPS" { v = $2 } END { print v }' "$log")
    T_AO=$(awk '$1 == "TESSERA_AO_MRAYPS" { v = $2 } END { print v }' "$log")
    # With more than one thread, bench also times the same work on one thread.
    T_1T=$(awk '$1 == "TESSERA_PRIMARY_MRAYPS_1T" { v = $2 } END { print v }' "$log")
}

ROWS=()
SCALE_ROWS=()
for MESH in "${MESHES[@]}"; do
    KEY=$(key_of "$MESH")
    LABEL=$MESH
    [[ $MESH == knot:* ]] || LABEL=$(basename -- "$MESH")
    note "mesh $LABEL"

    # Both renderers read the triangles Tessera's loader produced, written as OBJ by our
    # export-obj: one format Embree's loader reads fully, and exactly the same triangles.
    OBJ=$CACHE/meshes/$KEY.obj
    if [[ ! -s $OBJ || $NODE -nt $OBJ || ( -f $MESH && $MESH -nt $OBJ ) ]]; then
        run "$OUT/$KEY-export.log" "$LIMIT" "$NODE" export-obj --scene "$MESH" --out "$OBJ.tmp"
        mv -f "$OBJ.tmp" "$OBJ"
    fi

    # Camera framing the mesh (cached with the OBJ; keyed on size, fov, view dir, up and the helper).
    CAMFILE=$CACHE/meshes/$KEY.${WIDTH}x${HEIGHT}-$( (printf '%s' "$FOV $VIEW_DIR $UP"; cat "$SCRIPT_DIR/mesh-camera.py") | sha1sum | cut -c1-8).cam
    if [[ ! -s $CAMFILE || $OBJ -nt $CAMFILE ]]; then
        run "$CAMFILE.tmp" "$LIMIT" python3 "$SCRIPT_DIR/mesh-camera.py" "$OBJ" "$WIDTH" "$HEIGHT" \
            --fov "$FOV" --dir "$VIEW_DIR" --up "$UP"
        mv -f "$CAMFILE.tmp" "$CAMFILE"
    fi
    cam() { awk -v k="$1" '$1 == k { print $2 }' "$CAMFILE"; }
    TRIS=$(cam TRIANGLES) EYE=$(cam EYE) TARGET_P=$(cam TARGET) CAM_UP=$(cam UP) CAM_FOV=$(cam FOV)
    [[ -n $TRIS && -n $EYE && -n $TARGET_P && -n $CAM_UP && -n $CAM_FOV ]] || die "bad camera file $CAMFILE"
    EYE_S=${EYE//,/ } TARGET_S=${TARGET_P//,/ } UP_S=${CAM_UP//,/ }
    note "  $TRIS triangles; camera eye $EYE target $TARGET_P up $CAM_UP fov $CAM_FOV"

    E_MAIN=$(embree_run "${THREADS}t" "$THREADS")
    tessera_run "${THREADS}t" "$THREADS"
    T_MAIN=$T_PRIMARY
    ROWS+=("$(printf '%-22s %10s %10s %7s %14s %15s %15s' "$LABEL" "$TRIS" "$SIZE" "$THREADS" \
        "$E_MAIN" "$T_MAIN" "$(ratio "$T_MAIN" "$E_MAIN")")")
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$LABEL" "$TRIS" "$SIZE" "$THREADS" "$E_MAIN" \
        "$T_MAIN" "$(ratio "$T_MAIN" "$E_MAIN")" "$T_SHADOW" "$T_AO" >>"$RESULTS"

    if [[ $SCALING -eq 1 ]]; then
        declare -A T_BY=() E_BY=()
        T_BY[$THREADS]=$T_MAIN E_BY[$THREADS]=$E_MAIN
        [[ -n $T_1T ]] && T_BY[1]=$T_1T
        for n in 1 2; do
            if [[ -z ${T_BY[$n]:-} ]]; then
                tessera_run "${n}t" "$n"
                T_BY[$n]=$T_PRIMARY
                [[ -n $T_1T ]] && T_BY[1]=$T_1T
            fi
            [[ -n ${E_BY[$n]:-} ]] || E_BY[$n]=$(embree_run "${n}t" "$n")
        done
        SCALE_ROWS+=("$(printf '%-22s %12s %12s %9s %12s %12s %9s' "$LABEL" "${T_BY[1]}" "${T_BY[2]}" \
            "$(ratio "${T_BY[2]}" "${T_BY[1]}")" "${E_BY[1]}" "${E_BY[2]}" \
            "$(ratio "${E_BY[2]}" "${E_BY[1]}")")")
        printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$LABEL" "${T_BY[1]}" "${T_BY[2]}" \
            "$(ratio "${T_BY[2]}" "${T_BY[1]}")" "${E_BY[1]}" "${E_BY[2]}" \
            "$(ratio "${E_BY[2]}" "${E_BY[1]}")" >>"$SCALE"
        unset T_BY E_BY
    fi

    if [[ $REFERENCE -eq 1 ]]; then
        run "$OUT/$KEY-reference.log" "$LIMIT" "$MASTER" render --scene "$OBJ" --eye="$EYE" \
            --target="$TARGET_P" --up="$CAM_UP" --fov "$CAM_FOV" --wall 1x1 \
            --screen "${WIDTH}x${HEIGHT}" --out "$OUT/$KEY-reference"
        note "  reference image $OUT/$KEY-reference/wall.png; Embree's $OUT/$KEY-embree-${THREADS}t.ppm"
    fi
done

# --- 5. Report ---------------------------------------------------------------------------------
echo
echo "Primary rays, million rays per second (Embree: viewer BENCHMARK_RENDER_MRAYPS_AVG;"
echo "Tessera: render-node bench TESSERA_PRIMARY_MRAYPS), $FRAMES timed frames each:"
printf '%-22s %10s %10s %7s %14s %15s %15s\n' mesh triangles size threads "embree Mray/s" \
    "tessera Mray/s" "tessera/embree"
printf '%s\n' "${ROWS[@]}"
if [[ $SCALING -eq 1 ]]; then
    echo
    echo "Thread scaling of primary rays (Mray/s at 1 and 2 threads):"
    printf '%-22s %12s %12s %9s %12s %12s %9s\n' mesh "tessera 1t" "tessera 2t" "2t/1t" \
        "embree 1t" "embree 2t" "2t/1t"
    printf '%s\n' "${SCALE_ROWS[@]}"
fi
echo
echo "Results: $RESULTS, $SCALE; commands: $CMDS; logs and images: $OUT"
