#!/usr/bin/env bash
# A Tessera render node next to Embree 3 (Debian 12's embree-tools) at its best: primary rays
# against both `viewer` (single rays) and `viewer_stream` (8x8 ray streams), each at every ISA
# the CPU has (avx2, avx512), the faster taken; the like-for-like frame (Tessera's eye-light
# shading, the frame Embree's viewers draw) against the same, with Tessera's full frame (lights,
# shadows) beside it; ambient-occlusion rays against `viewer --shader
# ao`; BVH build rate against Embree's Mprim/s; bytes per triangle; 1 and N threads.
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
#   --isa NAME         one instruction set for both: Embree's --isa NAME and Tessera's
#                      TESSERA_ISA=NAME (avx2, avx512; default: each Embree ISA this CPU has,
#                      the faster taken, and Tessera's best)
#   --no-scaling       skip the 1-thread runs
#   --no-ao            skip the ambient-occlusion comparison (64 rays per hit: the slowest part)
#   --reference        also render Tessera's reference image (tessera-master render) per mesh
#   --embree DIR       Embree's viewer and viewer_stream from DIR rather than Debian's package
#                      (a machine without apt: copy them, with their libraries on
#                      LD_LIBRARY_PATH)
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
AO=1
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
        --isa) need_arg "$@"; ONE_ISA=$2; shift 2 ;;
        --no-scaling) SCALING=0; shift ;;
        --no-ao) AO=0; shift ;;
        --reference) REFERENCE=1; shift ;;
        --embree) need_arg "$@"; EMBREE_DIR=$2; shift 2 ;;
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
PACKAGES=()
[[ -n ${EMBREE_DIR:-} ]] || PACKAGES+=(embree-tools)
for mesh in "${MESHES[@]}"; do
    case $mesh in
        /usr/share/assimp/*) PACKAGES+=(assimp-testmodels) ;;
        /usr/share/glmark2/*) PACKAGES+=(glmark2-data) ;;
    esac
done
MISSING=()
for pkg in $(printf '%s\n' "${PACKAGES[@]+"${PACKAGES[@]}"}" | sort -u); do
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
VIEWER=${EMBREE_DIR:-/usr/bin}/viewer
STREAM=${EMBREE_DIR:-/usr/bin}/viewer_stream
[[ -x $VIEWER && -x $STREAM ]] || die "$VIEWER or $STREAM (package embree-tools) not found"
MISSING_LIBS=$( (ldd "$VIEWER" "$STREAM" 2>&1 || true) | awk '/not found/ { print $1 }' | sort -u | tr '\n' ' ')
[[ -z $MISSING_LIBS ]] || die "Embree's viewers lack libraries: $MISSING_LIBS(set LD_LIBRARY_PATH)"
# Embree picks its ISA per run; we measure each one this CPU has and keep the faster.
ISAS=(avx2)
grep -qw avx512f /proc/cpuinfo && ISAS+=(avx512)
grep -qw avx2 /proc/cpuinfo || ISAS=(sse4.2)
if [[ -n ${ONE_ISA:-} ]]; then
    case $ONE_ISA in
        avx2) grep -qw avx2 /proc/cpuinfo || die "--isa avx2: this CPU has no AVX2" ;;
        avx512) grep -qw avx512f /proc/cpuinfo || die "--isa avx512: this CPU has no AVX-512" ;;
        *) die "--isa must be avx2 or avx512, got $ONE_ISA" ;;
    esac
    ISAS=("$ONE_ISA")
    export TESSERA_ISA=$ONE_ISA
fi
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
printf 'mesh\ttriangles\tsize\tthreads\tviewer\tviewer_stream\tembree_best\tembree_mode\ttessera_primary\tratio\ttessera_shaded\tshaded_ratio\ttessera_eyelight\teyelight_ratio\ttessera_full\tfull_ratio\n' >"$RESULTS"
AO_TSV=$OUT/ao.tsv
printf 'mesh\tthreads\thits\tembree_ao_fps\tembree_ao_mrayps\ttessera_ao_mrayps\tratio\ttessera_surface_mrayps\tsurface_ratio\n' >"$AO_TSV"
BUILD_TSV=$OUT/build.tsv
printf 'mesh\tthreads\tembree_mprims\ttessera_build_mtris\tratio\ttessera_cache_load_s\tbytes_per_triangle\tarray_bytes_per_triangle\n' >"$BUILD_TSV"

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

figure() {  # figure NAME LOG: the value on the line "NAME value ..."
    local v
    v=$(awk -v n="$1" '$1 == n { v = $2 } END { print v }' "$2")
    [[ $v =~ ^[0-9]+([.][0-9]*)?([eE][-+]?[0-9]+)?$ ]] || die "no $1 figure in $2"
    echo "$v"
}

ratio() { awk -v a="$1" -v b="$2" 'BEGIN { if (b > 0) printf "%.3f", a / b; else print "n/a" }'; }
max_of() { awk -v a="$1" -v b="$2" 'BEGIN { print (a + 0 >= b + 0) ? a : b }'; }

# embree_run PROGRAM ISA THREADS [SHADER] -> prints the log's path. Checks the triangle count.
embree_run() {
    local prog=$1 isa=$2 threads=$3 shader=${4:-default}
    local tag log frames=$FRAMES
    tag=$(basename "$prog")-$isa-${threads}t-$shader
    log=$OUT/$KEY-embree-$tag.log
    [[ $shader == ao ]] && frames=3
    run "$log" "$LIMIT" "$prog" -i "$OBJ" -o "$OUT/$KEY-embree-$tag.ppm" \
        --size "$WIDTH" "$HEIGHT" --vp $EYE_S --vi $TARGET_S --vu $UP_S --fov "$CAM_FOV" \
        --threads "$threads" --isa "$isa" --shader "$shader" --verbose 2 --benchmark 1 "$frames" --legacy
    local loaded
    loaded=$(awk -F: '/# triangles/ { gsub(/ /, "", $2); v = $2 } END { print v }' "$log")
    [[ $loaded == "$TRIS" ]] || die "Embree loaded ${loaded:-no} triangles from $OBJ, expected $TRIS"
    echo "$log"
}

# embree_build LOG -> the Mprim/s of the BVH build the log reports (0 if none).
embree_build() {
    local v
    v=$(sed -n 's/.*finished BVH.* \([0-9.]*\) Mprim\/s.*/\1/p' "$1" | tail -n 1)
    echo "${v:-0}"
}

# embree_sah LOG -> "total nodes leaves" of the tree's SAH as Embree's verbose statistics print
# it ("n/a n/a n/a" if the log has none).
embree_sah() {
    awk '$2 == ":" && $3 == "sah" && !seen[$1]++ { v[$1] = $5 }
        END { printf "%s %s %s\n", v["total"] ? v["total"] : "n/a",
              v["getAABBNodes"] ? v["getAABBNodes"] : "n/a", v["leaves"] ? v["leaves"] : "n/a" }' "$1"
}

# tessera_sah LOG -> "total nodes leaves" from TESSERA_TREE_SAH, the same statistic of ours.
tessera_sah() {
    sed -n 's/^TESSERA_TREE_SAH \([0-9.]*\) (inner nodes \([0-9.]*\), leaves \([0-9.]*\) .*/\1 \2 \3/p' "$1" |
        tail -n 1 | grep . || echo "n/a n/a n/a"
}

# embree_primary THREADS [ISA...] -> sets E_VIEWER E_STREAM (best over the ISAs, with the ISA in
# E_VIEWER_ISA / E_STREAM_ISA), E_BEST, E_MODE and E_BUILD (the best Mprim/s of these runs'
# builds: one build varies by 2x from run to run, 1.7 to 4.7 Mprim/s on the dragon).
embree_primary() {
    local threads=$1 isa log v
    shift
    E_VIEWER=0 E_STREAM=0 E_BUILD=
    for isa in "$@"; do
        log=$(embree_run "$VIEWER" "$isa" "$threads")
        E_TREE_LOG=$log
        v=$(figure BENCHMARK_RENDER_MRAYPS_AVG "$log")
        if awk -v a="$v" -v b="$E_VIEWER" 'BEGIN { exit !(a > b) }'; then E_VIEWER=$v E_VIEWER_ISA=$isa; fi
        E_BUILD=$(max_of "$(embree_build "$log")" "${E_BUILD:-0}")
        log=$(embree_run "$STREAM" "$isa" "$threads")
        E_BUILD=$(max_of "$(embree_build "$log")" "$E_BUILD")
        v=$(figure BENCHMARK_RENDER_MRAYPS_AVG "$log")
        if awk -v a="$v" -v b="$E_STREAM" 'BEGIN { exit !(a > b) }'; then E_STREAM=$v E_STREAM_ISA=$isa; fi
    done
    if awk -v a="$E_STREAM" -v b="$E_VIEWER" 'BEGIN { exit !(a > b) }'; then
        E_BEST=$E_STREAM E_MODE="viewer_stream/$E_STREAM_ISA" E_BEST_PROG=$STREAM E_BEST_ISA=$E_STREAM_ISA
    else
        E_BEST=$E_VIEWER E_MODE="viewer/$E_VIEWER_ISA" E_BEST_PROG=$VIEWER E_BEST_ISA=$E_VIEWER_ISA
    fi
}

# tessera_run TAG THREADS [EXTRA...] -> prints the log's path.
tessera_run() {
    local tag=$1 threads=$2 log=$OUT/$KEY-tessera-$1.log
    shift 2
    run "$log" "$LIMIT" "$NODE" bench --scene "$OBJ" --size "${WIDTH}x${HEIGHT}" \
        --threads "$threads" --eye="$EYE" --target="$TARGET_P" --up="$CAM_UP" --fov "$CAM_FOV" \
        --bvh-cache "$OUT/bvh-cache" "$@"
    echo "$log"
}

ROWS=()
AO_ROWS=()
BUILD_ROWS=()
TREE_ROWS=()
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

    # Primary rays at N threads (and 1), with the build (a fresh cache: this run builds it).
    rm -rf "$OUT/bvh-cache"
    TLOG=$(tessera_run "${THREADS}t" "$THREADS" --frames "$FRAMES" $([[ $SCALING -eq 1 ]] || echo --no-scaling))
    T_MAIN=$(figure TESSERA_PRIMARY_MRAYPS "$TLOG")
    T_SHADED=$(figure TESSERA_SHADED_MRAYPS "$TLOG")
    T_EYE=$(figure TESSERA_EYELIGHT_MRAYPS "$TLOG")
    T_FULL=$(figure TESSERA_FULL_MRAYPS "$TLOG")
    T_BUILD=$(figure TESSERA_BUILD_MTRIS_PER_S "$TLOG")
    T_BYTES=$(figure TESSERA_BYTES_PER_TRIANGLE "$TLOG")
    T_ARRAY=$(figure TESSERA_ARRAY_BYTES_PER_TRIANGLE "$TLOG")
    embree_primary "$THREADS" "${ISAS[@]}"
    # The build row compares builds at N threads: the 1-thread runs below set E_BUILD again
    # (until 2026-12-04 the row took theirs, Embree's 1-thread build against ours at N).
    E_BUILD_N=$E_BUILD
    read -r E_SAH E_SAH_NODES E_SAH_LEAVES < <(embree_sah "$E_TREE_LOG")
    read -r T_SAH T_SAH_NODES T_SAH_LEAVES < <(tessera_sah "$TLOG")
    TREE_ROWS+=("$(printf '%-22s %12s %12s %12s %12s %12s %12s' "$LABEL" "$E_SAH_NODES" "$T_SAH_NODES" \
        "$E_SAH_LEAVES" "$T_SAH_LEAVES" "$E_SAH" "$T_SAH")")
    ROWS+=("$(printf '%-22s %9s %7s %16s %16s %16s %9s %9s %9s %9s %9s %9s %9s %9s' "$LABEL" "$TRIS" \
        "$THREADS" "$E_VIEWER/$E_VIEWER_ISA" "$E_STREAM/$E_STREAM_ISA" "$E_MODE" "$T_MAIN" \
        "$(ratio "$T_MAIN" "$E_BEST")" "$T_EYE" "$(ratio "$T_EYE" "$E_BEST")" \
        "$T_SHADED" "$(ratio "$T_SHADED" "$E_BEST")" "$T_FULL" "$(ratio "$T_FULL" "$E_BEST")")")
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$LABEL" "$TRIS" \
        "$SIZE" "$THREADS" "$E_VIEWER" "$E_STREAM" "$E_BEST" "$E_MODE" "$T_MAIN" \
        "$(ratio "$T_MAIN" "$E_BEST")" "$T_SHADED" "$(ratio "$T_SHADED" "$E_BEST")" \
        "$T_EYE" "$(ratio "$T_EYE" "$E_BEST")" "$T_FULL" "$(ratio "$T_FULL" "$E_BEST")" >>"$RESULTS"
    BEST_ISA_N=$E_BEST_ISA
    if [[ $SCALING -eq 1 && $THREADS -gt 1 ]]; then
        T_1T=$(figure TESSERA_PRIMARY_MRAYPS_1T "$TLOG")
        E_N=$E_BEST
        embree_primary 1 "$BEST_ISA_N"
        ROWS+=("$(printf '%-22s %9s %7s %16s %16s %16s %9s %9s %9s %9s %9s %9s %9s %9s' "$LABEL" \
            "$TRIS" 1 "$E_VIEWER/$E_VIEWER_ISA" "$E_STREAM/$E_STREAM_ISA" "$E_MODE" "$T_1T" \
            "$(ratio "$T_1T" "$E_BEST")" - - - - - -)")
        printf '%s\t%s\t%s\t1\t%s\t%s\t%s\t%s\t%s\t%s\t\t\t\t\t\t\n' "$LABEL" "$TRIS" "$SIZE" \
            "$E_VIEWER" "$E_STREAM" "$E_BEST" "$E_MODE" "$T_1T" "$(ratio "$T_1T" "$E_BEST")" >>"$RESULTS"
        ROWS+=("$(printf '%-22s %9s %7s   scaling %dt/1t: embree %s, tessera %s' "$LABEL" "" "" "$THREADS" \
            "$(ratio "$E_N" "$E_BEST")" "$(ratio "$T_MAIN" "$T_1T")")")
    fi

    # The build: Embree's BVH8 SAH builder against ours, and our cache (same fresh cache).
    CLOG=$(tessera_run cached "$THREADS" --frames 1 --no-scaling)
    T_LOAD=$(figure TESSERA_BVH_CACHE_LOAD_S "$CLOG")
    BUILD_ROWS+=("$(printf '%-22s %7s %14s %16s %8s %14s %10s %10s' "$LABEL" "$THREADS" "${E_BUILD_N:-n/a}" \
        "$T_BUILD" "$(ratio "$T_BUILD" "${E_BUILD_N:-0}")" "$T_LOAD" "$T_BYTES" "$T_ARRAY")")
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$LABEL" "$THREADS" "${E_BUILD_N:-}" "$T_BUILD" \
        "$(ratio "$T_BUILD" "${E_BUILD_N:-0}")" "$T_LOAD" "$T_BYTES" "$T_ARRAY" >>"$BUILD_TSV"

    # Ambient occlusion: Embree's ao shader traces 64 occlusion rays per primary hit with
    # rtcOccluded1, from the hit point, tnear 0.001, unbounded, and so do we (TESSERA_AO_MRAYPS);
    # its rays/s are its frame rate times our hit count times 64 (its frame also holds the
    # primary rays and shading, which favours us by at most 1/65). Our rays from the renderer's
    # own start (t from 0, a few ulps off the surface) are reported beside them.
    if [[ $AO -eq 1 ]]; then
        ALOG=$(tessera_run ao "$THREADS" --frames 2 --no-scaling --ao 64 --ao-unbounded)
        T_AO=$(figure TESSERA_AO_MRAYPS "$ALOG")
        T_AO_SURFACE=$(figure TESSERA_AO_SURFACE_MRAYPS "$ALOG")
        HITS=$(figure TESSERA_PRIMARY_HITS "$ALOG")
        ELOG=$(embree_run "$VIEWER" "$BEST_ISA_N" "$THREADS" ao)
        FPS=$(figure BENCHMARK_RENDER_AVG "$ELOG")
        E_AO=$(awk -v f="$FPS" -v h="$HITS" 'BEGIN { printf "%.3f", f * h * 64 / 1e6 }')
        AO_ROWS+=("$(printf '%-22s %7s %10s %10s %14s %15s %9s %15s %9s' "$LABEL" "$THREADS" "$HITS" \
            "$FPS" "$E_AO" "$T_AO" "$(ratio "$T_AO" "$E_AO")" "$T_AO_SURFACE" \
            "$(ratio "$T_AO_SURFACE" "$E_AO")")")
        printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$LABEL" "$THREADS" "$HITS" "$FPS" "$E_AO" \
            "$T_AO" "$(ratio "$T_AO" "$E_AO")" "$T_AO_SURFACE" "$(ratio "$T_AO_SURFACE" "$E_AO")" >>"$AO_TSV"
    fi

    if [[ $REFERENCE -eq 1 ]]; then
        run "$OUT/$KEY-reference.log" "$LIMIT" "$MASTER" render --scene "$OBJ" --eye="$EYE" \
            --target="$TARGET_P" --up="$CAM_UP" --fov "$CAM_FOV" --wall 1x1 \
            --screen "${WIDTH}x${HEIGHT}" --out "$OUT/$KEY-reference"
        note "  reference image $OUT/$KEY-reference/wall.png; Embree's $OUT/$KEY-embree-*.ppm"
    fi
done

# --- 5. Report ---------------------------------------------------------------------------------
echo
echo "Primary rays, Mrays/s at $SIZE ($FRAMES timed frames; Embree: BENCHMARK_RENDER_MRAYPS_AVG of"
echo "viewer and viewer_stream at each ISA, the faster named; Tessera: render-node bench, fastest"
echo "frame). Whole frames, rays generated, traced, shaded and stored as RGB8: 'eyelight' is the"
echo "like-for-like one (|N.D| times the base colour, the frame Embree's viewers draw, their ratio"
echo "against the faster viewer), 'shaded' lights without shadows, 'full' lights and shadows (the"
echo "wall's default, its shadow rays not counted in Mrays/s):"
printf '%-22s %9s %7s %16s %16s %16s %9s %9s %9s %9s %9s %9s %9s %9s\n' mesh triangles threads \
    "viewer/isa" "stream/isa" "faster" primary ratio eyelight ratio shaded ratio full ratio
printf '%s\n' "${ROWS[@]}"
echo
echo "BVH build, million triangles/s (Embree: its BVH8 SAH builder's Mprim/s; Tessera: obvhs build"
echo "and the 8-wide collapse), the cache's load time, and the render node's bytes per triangle:"
printf '%-22s %7s %14s %16s %8s %14s %10s %10s\n' mesh threads "embree Mprim/s" "tessera Mtris/s" \
    ratio "cache load s" "B/tri" "array B/tri"
printf '%s\n' "${BUILD_ROWS[@]}"
echo
echo "The trees by the surface area heuristic, as Embree's verbose statistics count it (box areas"
echo "over the root's: inner nodes each once, leaves times their blocks of 4 triangles; lower is a"
echo "tree that asks fewer visits of a ray through the root, uniform over directions):"
printf '%-22s %12s %12s %12s %12s %12s %12s\n' mesh "embree nodes" "ours nodes" "embree leaves" \
    "ours leaves" "embree total" "ours total"
printf '%s\n' "${TREE_ROWS[@]}"
if [[ $AO -eq 1 ]]; then
    echo
    echo "Ambient occlusion, 64 unbounded rays per hit from t = 0.001 (Embree: viewer --shader ao at"
    echo "the ISA above; 'surface': ours from the renderer's start, a few ulps off, t from 0):"
    printf '%-22s %7s %10s %10s %14s %15s %9s %15s %9s\n' mesh threads hits "embree fps" \
        "embree Mray/s" "tessera Mray/s" ratio "surface Mray/s" ratio
    printf '%s\n' "${AO_ROWS[@]}"
fi
echo
echo "Results: $RESULTS, $BUILD_TSV, $AO_TSV; commands: $CMDS; logs and images: $OUT"
