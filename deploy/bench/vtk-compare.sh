#!/usr/bin/env bash
# Tessera's volume ray marching next to VTK's CPU volume ray caster
# (vtkFixedPointVolumeRayCastMapper, PyPI `vtk`): the same volume, transfer function, camera,
# image size, sample distance and thread count. Prints both frame times, their ratio, and each
# one's RMSE against its own converged image (the same renderer at a sixteenth of the step).
# Where Tessera's error is above VTK's, Tessera is rendered again at finer steps until it is not,
# and the ratio at no more error uses that time.
#
#   deploy/bench/vtk-compare.sh [--volume V.vol.toml] [--size 1024x768] [--threads N]
#                               [--frames K] [--step S] [--out DIR]
#
# Options:
#   --volume V     a raw volume with a Tessera sidecar (default: the CT head of Debian's
#                  invesalius-examples, unpacked by deploy/volumes/fetch-cranium.sh)
#   --size WxH     image size (default 1024x768)
#   --threads N    threads for both (default: nproc)
#   --frames K     timed frames of each (default 5; each renderer also renders one untimed)
#   --step S       sample distance in world units (default: half the smallest voxel spacing)
#   --out DIR      images and logs (default ~/.cache/tessera-bench/vtk-runs/DATE)
#
# The transfer function is CT bone (Hounsfield units), written as a file both read; shading is
# off in both (Tessera's ray marching is emission-absorption), interpolation trilinear. Each
# RMSE is over linear RGB in 0..1 of the whole image: Tessera's from its --aov color PFM,
# VTK's from its 8-bit frame buffer (VTK does not encode a gamma; its 8 bits leave an error
# floor of about 0.001). Backgrounds differ (Tessera's sky gradient, VTK's black) but cancel in
# each renderer's own comparison.
set -euo pipefail
die() { echo "vtk-compare: error: $*" >&2; exit 1; }
note() { echo "vtk-compare: $*" >&2; }

SCRIPT_DIR=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$SCRIPT_DIR/../.." && pwd)
CACHE=${XDG_CACHE_HOME:-$HOME/.cache}/tessera-bench
VOLUME=
SIZE=1024x768
THREADS=$(nproc)
FRAMES=5
STEP=
OUT=
need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value"; }
while [[ $# -gt 0 ]]; do
    case $1 in
        --volume) need_arg "$@"; VOLUME=$2; shift 2 ;;
        --size) need_arg "$@"; SIZE=$2; shift 2 ;;
        --threads) need_arg "$@"; THREADS=$2; shift 2 ;;
        --frames) need_arg "$@"; FRAMES=$2; shift 2 ;;
        --step) need_arg "$@"; STEP=$2; shift 2 ;;
        --out) need_arg "$@"; OUT=$2; shift 2 ;;
        -h|--help) sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$0"; exit 0 ;;
        *) die "unknown argument: $1 (see --help)" ;;
    esac
done
[[ $SIZE =~ ^([1-9][0-9]*)x([1-9][0-9]*)$ ]] || die "--size must be WxH, got $SIZE"
[[ $THREADS =~ ^[1-9][0-9]*$ ]] || die "--threads must be a positive integer"
[[ $FRAMES =~ ^[1-9][0-9]*$ ]] || die "--frames must be a positive integer"
OUT=${OUT:-$CACHE/vtk-runs/$(date +%Y%m%d-%H%M%S)}
mkdir -p "$OUT"
[[ -n $VOLUME ]] || VOLUME=$(bash "$ROOT/deploy/volumes/fetch-cranium.sh")
[[ -f $VOLUME ]] || die "no volume at $VOLUME"

VENV=$CACHE/vtk-venv
if [[ ! -x $VENV/bin/python ]] || ! "$VENV/bin/python" -c 'import vtk, numpy' 2>/dev/null; then
    note "installing vtk and numpy from PyPI into $VENV"
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q vtk numpy
fi
PY=$VENV/bin/python

note "building tessera-master (release)"
(cd "$ROOT" && cargo build --release -q -p tessera-master)
MASTER=${CARGO_TARGET_DIR:-$ROOT/target}/release/tessera-master

cat > "$OUT/ct-bone.toml" <<'TOML'
domain = "data"
[[point]]
value = 150.0
color = [0.6, 0.3, 0.2]
opacity = 0.0
[[point]]
value = 250.0
color = [0.9, 0.75, 0.6]
opacity = 0.3
[[point]]
value = 600.0
color = [1.0, 0.95, 0.85]
opacity = 0.8
[[point]]
value = 2000.0
color = [1.0, 1.0, 1.0]
opacity = 0.95
TOML

# The camera: in front of the volume's middle (along -y, z up), far enough that its bounding
# sphere fills the view; the step: half the smallest spacing unless given.
read -r EYE TARGET SPACING < <("$PY" - "$VOLUME" <<'PY'
import math, sys, tomllib
side = tomllib.load(open(sys.argv[1], "rb"))
dims, sp = side["dims"], side["spacing"]
org = side.get("origin", [0, 0, 0])
c = [o + (d - 1) * s / 2 for o, d, s in zip(org, dims, sp)]
r = math.sqrt(sum(((d - 1) * s / 2) ** 2 for d, s in zip(dims, sp)))
dist = r / math.sin(math.radians(40) / 2) * 0.9
eye = [c[0] + 0.35 * dist, c[1] - 0.9 * dist, c[2] + 0.25 * dist]
n = math.sqrt(0.35**2 + 0.9**2 + 0.25**2)
eye = [c[i] + (eye[i] - c[i]) / n for i in range(3)]
print(",".join(f"{v:.4f}" for v in eye), ",".join(f"{v:.4f}" for v in c), min(sp))
PY
)
STEP=${STEP:-$("$PY" -c "print($SPACING / 2)")}
FINE=$("$PY" -c "print($STEP / 16)")
CAM=(--eye "$EYE" --target "$TARGET" --up 0,0,1 --fov 40)
note "volume $VOLUME, ${SIZE}, $THREADS threads, step $STEP (reference $FINE), eye $EYE"

tessera() { # STEP DIR REPEAT
    RAYON_NUM_THREADS=$THREADS "$MASTER" render --wall 1x1 --screen "$SIZE" --scene "$VOLUME" \
        --transfer "$OUT/ct-bone.toml" --volume-step "$1" --no-shadows "${CAM[@]}" \
        --repeat "$3" --aov color --out "$2" 2> "$2.log" || { cat "$2.log" >&2; die "tessera failed"; }
}
vtkrun() { # STEP OUT.npy FRAMES
    "$PY" "$SCRIPT_DIR/vtk-volume.py" --volume "$VOLUME" --transfer "$OUT/ct-bone.toml" \
        --size "$SIZE" "${CAM[@]}" --step "$1" --threads "$THREADS" --frames "$3" \
        --out "$2" 2> "$2.log" | grep '^VTK_TIMES' || { cat "$2.log" >&2; die "vtk failed"; }
}

note "Tessera at the step, then at a sixteenth of it (the reference)"
mkdir -p "$OUT/tessera" "$OUT/tessera-ref"
tessera "$STEP" "$OUT/tessera" "$((FRAMES + 1))"
tessera "$FINE" "$OUT/tessera-ref" 1
note "VTK at the step, then at a sixteenth of it"
VTK_LINE=$(vtkrun "$STEP" "$OUT/vtk.npy" "$FRAMES")
vtkrun "$FINE" "$OUT/vtk-ref.npy" 1 > /dev/null

median_of() { # LOG
    local m; m=$(sed -n 's/.*median \([0-9.]*\) s.*/\1/p' "$1")
    [[ -n $m ]] || die "no render time in $1"
    echo "$m"
}
rmse_of() { # A B (each a Tessera PFM or a VTK .npy)
    "$PY" - "$1" "$2" <<'PY'
import sys
import numpy as np

def load(path):
    if path.endswith(".npy"):
        return np.load(path)
    with open(path, "rb") as f:
        assert f.readline().strip() == b"PF"
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    return data.reshape(h, w, 3)[::-1]

a, b = load(sys.argv[1]), load(sys.argv[2])
print(f"{np.sqrt(np.mean((a.astype(np.float64) - b) ** 2)):.6e}")
PY
}
T_MEDIAN=$(median_of "$OUT/tessera.log")
read -r _ V_FIRST V_MEDIAN V_FASTEST <<< "$VTK_LINE"
T_ERR=$(rmse_of "$OUT/tessera/color.pfm" "$OUT/tessera-ref/color.pfm")
V_ERR=$(rmse_of "$OUT/vtk.npy" "$OUT/vtk-ref.npy")

# "Faster at no more error": where Tessera's error at the shared step is above VTK's, it is
# rendered again at finer steps until its error is no more than VTK's, and that time counts.
MATCHED_STEP=$STEP MATCHED_MEDIAN=$T_MEDIAN MATCHED_ERR=$T_ERR
if "$PY" -c "import sys; sys.exit(not $T_ERR > $V_ERR)"; then
    MATCHED_STEP=
    for f in 0.95 0.9 0.85 0.8 0.7 0.6 0.5; do
        s=$("$PY" -c "print($STEP * $f)")
        note "Tessera's error is above VTK's: again at step $s ($f of it)"
        mkdir -p "$OUT/tessera-$f"
        tessera "$s" "$OUT/tessera-$f" "$((FRAMES + 1))"
        e=$(rmse_of "$OUT/tessera-$f/color.pfm" "$OUT/tessera-ref/color.pfm")
        if "$PY" -c "import sys; sys.exit(not $e <= $V_ERR)"; then
            MATCHED_STEP=$s MATCHED_MEDIAN=$(median_of "$OUT/tessera-$f.log") MATCHED_ERR=$e
            break
        fi
    done
fi

"$PY" - "$STEP" "$T_MEDIAN" "$T_ERR" "$V_MEDIAN" "$V_ERR" "$MATCHED_STEP" "$MATCHED_MEDIAN" "$MATCHED_ERR" <<'PY'
import sys
step, t, t_err, v, v_err = map(float, sys.argv[1:6])
m_step, m_t, m_err = sys.argv[6:9]
print("| renderer | step | frame time (median) | RMSE against its own step/16 image |")
print("| --- | ---: | ---: | ---: |")
print(f"| Tessera | {step:.4g} | {t * 1000:.1f} ms | {t_err:.2e} |")
if m_step and float(m_step) != step:
    print(f"| Tessera, error matched | {float(m_step):.4g} | {float(m_t) * 1000:.1f} ms | {float(m_err):.2e} |")
print(f"| VTK vtkFixedPointVolumeRayCastMapper | {step:.4g} | {v * 1000:.1f} ms | {v_err:.2e} |")
print(f"speed at the same step: Tessera / VTK = {v / t:.2f}x (VTK time over Tessera time)")
print(f"error at the same step: Tessera / VTK = {t_err / v_err:.2f}" if v_err > 0 else "error: VTK's is 0")
if m_step:
    print(f"speed at no more error than VTK: {v / float(m_t):.2f}x (Tessera at step {float(m_step):.4g})")
else:
    print("speed at no more error than VTK: none found (Tessera's error stayed above VTK's down to half the step)")
PY
note "images and logs in $OUT"
