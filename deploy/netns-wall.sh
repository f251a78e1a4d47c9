#!/usr/bin/env bash
# A Tessera wall across network namespaces on one machine: every node in a namespace of its own,
# with its own address, joined by veth pairs to a bridge in a hub namespace; optionally a netem
# delay and loss on every node's link. Runs `tessera-master serve` and the nodes the way
# deploy/README.md describes for real hosts, then prints the run's figures from report.json.
#
#   deploy/netns-wall.sh [OPTIONS]                 # run a wall (as root)
#   deploy/netns-wall.sh --check [--delay MS] [--loss PCT]
#   deploy/netns-wall.sh --cleanup PREFIX          # remove a --keep'd or SIGKILLed run's namespaces
#
# Options:
#   --wall CxR          screens as columns x rows (default 2x2)
#   --screen WxH        pixels of one screen (default 320x180)
#   --bezel PX          pixels hidden between screens (default 0)
#   --render-nodes N    render nodes, one namespace each (default 2)
#   --threads N         threads per render node (default: cores / render nodes, at least 1)
#   --frames N          frames to render (default 100)
#   --scene S           the master's --scene (default builtin)
#   --delay MS          netem: one-way delay added to every packet a node sends (needs sch_netem)
#   --loss PCT          netem: percentage of the packets a node sends that are dropped
#   --out DIR           report.json and logs/ go here (default: a new /tmp/netns-wall.XXXXXX)
#   --bin-dir DIR       where the tessera binaries are (default ${CARGO_TARGET_DIR:-target}/release,
#                       else .../debug)
#   --prefix NAME       namespace name prefix, [a-z0-9-], at most 24 chars (default tw-PID-RANDOM)
#   --subnet A.B.C      the /24 the nodes get addresses in (default 10.77.0)
#   --timeout SEC       longest the wall may take, joining included (default 600)
#   --keep              leave the namespaces and the cert dir for inspection (processes still stop)
#   --check             only test whether namespaces (and netem) are usable here; one line each;
#                       exit 0 if usable, 77 if not (77 too if --delay/--loss and netem is not)
#   --cleanup PREFIX    kill what runs in, and delete, the namespaces PREFIX-{hub,m,rN,dN}
#   -h, --help          this text
#
# Addresses: master A.B.C.1 (port 7400), render node i A.B.C.(10+i), display i A.B.C.(100+i)
# (port 7401). Each run's hub is a namespace of its own, so nothing is added to the host's
# network and parallel runs cannot see each other, whatever their subnets.
# Exit: 0 wall ran and every display presented every frame; 1 failure; 77 this machine cannot
# (not root, no iproute2, the kernel refuses namespaces, or netem asked for and missing);
# 124 --timeout; 130/143 interrupted. The namespaces and processes are removed on every exit
# the script can trap; after a SIGKILL, use --cleanup PREFIX.
set -euo pipefail

PROG=netns-wall
die() { echo "$PROG: error: $*" >&2; exit 1; }
skip() { echo "$PROG: cannot run here: $*" >&2; exit 77; }
say() { echo "$PROG: $*" >&2; }

usage() {
    sed -n '2,/^set -euo/{/^set -euo/d; s/^# \{0,1\}//; p}' "$0"
    exit "${1:-0}"
}

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

WALL=2x2 SCREEN=320x180 BEZEL=0 RENDER_NODES=2 THREADS="" FRAMES=100 SCENE=builtin
DELAY="" LOSS="" OUT="" BIN_DIR="" PREFIX="" SUBNET=10.77.0 TIMEOUT=600 KEEP=0 MODE=run
CLEANUP_PREFIX=""

need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value (see --help)"; }
while [[ $# -gt 0 ]]; do
    case $1 in
        --wall) need_arg "$@"; WALL=$2; shift 2 ;;
        --screen) need_arg "$@"; SCREEN=$2; shift 2 ;;
        --bezel) need_arg "$@"; BEZEL=$2; shift 2 ;;
        --render-nodes) need_arg "$@"; RENDER_NODES=$2; shift 2 ;;
        --threads) need_arg "$@"; THREADS=$2; shift 2 ;;
        --frames) need_arg "$@"; FRAMES=$2; shift 2 ;;
        --scene) need_arg "$@"; SCENE=$2; shift 2 ;;
        --delay) need_arg "$@"; DELAY=$2; shift 2 ;;
        --loss) need_arg "$@"; LOSS=$2; shift 2 ;;
        --out) need_arg "$@"; OUT=$2; shift 2 ;;
        --bin-dir) need_arg "$@"; BIN_DIR=$2; shift 2 ;;
        --prefix) need_arg "$@"; PREFIX=$2; shift 2 ;;
        --subnet) need_arg "$@"; SUBNET=$2; shift 2 ;;
        --timeout) need_arg "$@"; TIMEOUT=$2; shift 2 ;;
        --keep) KEEP=1; shift ;;
        --check) MODE=check; shift ;;
        --cleanup) need_arg "$@"; MODE=cleanup; CLEANUP_PREFIX=$2; shift 2 ;;
        -h | --help) usage 0 ;;
        *) echo "$PROG: unknown option: $1" >&2; usage 2 >&2 ;;
    esac
done

is_uint() { [[ $1 =~ ^[0-9]+$ ]]; }
is_num() { [[ $1 =~ ^[0-9]+([.][0-9]+)?$ ]]; }
valid_prefix() { [[ $1 =~ ^[a-z][a-z0-9-]{1,23}$ ]]; }

[[ -z $DELAY ]] || is_num "$DELAY" || die "--delay must be milliseconds, e.g. 2 or 0.5 (got '$DELAY')"
if [[ -n $LOSS ]]; then
    is_num "$LOSS" || die "--loss must be a percentage, e.g. 1 or 0.5 (got '$LOSS')"
    awk -v l="$LOSS" 'BEGIN { exit !(l <= 100) }' || die "--loss must be at most 100"
fi
WANT_NETEM=0
[[ -z $DELAY && -z $LOSS ]] || WANT_NETEM=1

# The namespaces of a run: PREFIX-hub (the bridge), PREFIX-m, PREFIX-rN, PREFIX-dN. Matched
# exactly, so a prefix never catches another run's namespaces (tw-1 does not match tw-12-…).
run_namespaces() {
    local prefix=$1
    ip netns list 2>/dev/null | awk '{ print $1 }' \
        | grep -E "^${prefix//./\\.}-(hub|chk|m|r[0-9]+|d[0-9]+)\$" || true
}

remove_namespaces() {
    local prefix=$1 ns pid
    for ns in $(run_namespaces "$prefix"); do
        # Whatever still runs in a namespace of ours is ours: a node a SIGKILLed run left behind.
        for pid in $(ip netns pids "$ns" 2>/dev/null); do
            kill -KILL "$pid" 2>/dev/null || true
        done
        ip netns del "$ns" 2>/dev/null || say "warning: could not delete namespace $ns"
    done
}

# --- Can this machine do it? -------------------------------------------------------------------

# The probe namespace (PREFIX-chk); deleted by check_cleanup, and by `cleanup` in a run.
CHECK_NS="" REASON=""
check_cleanup() {
    [[ -z $CHECK_NS ]] || ip netns del "$CHECK_NS" 2>/dev/null || true
    CHECK_NS=""
}

# try WHAT COMMAND...: runs COMMAND; on failure sets REASON to WHAT and its first error line.
try() {
    local what=$1 err
    shift
    if ! err=$("$@" 2>&1 >/dev/null); then
        REASON="$what: '$(head -n 1 <<<"$err" | tr -s ' \t' ' ')'"
        return 1
    fi
}

# Returns 0 if namespaces, veth pairs and bridges work (leaving CHECK_NS=$1 to test netem in);
# else sets REASON.
namespaces_usable() {
    [[ $(id -u) -eq 0 ]] || { REASON="not root (ip netns needs root)"; return 1; }
    command -v ip >/dev/null || { REASON="ip (iproute2) not found"; return 1; }
    try "the kernel refused 'ip netns add'" ip netns add "$1" || return 1
    CHECK_NS=$1
    try "the kernel refused a veth pair" ip -n "$1" link add a0 type veth peer name a1 || return 1
    try "the kernel refused a bridge" ip -n "$1" link add br0 type bridge || return 1
}

# Returns 0 if a netem qdisc can be added in CHECK_NS; else sets REASON.
netem_usable() {
    command -v tc >/dev/null || { REASON="tc (iproute2) not found"; return 1; }
    if ! try "tc refused a netem qdisc" \
        ip netns exec "$CHECK_NS" tc qdisc add dev a0 root netem delay 1ms loss 1%; then
        REASON="$REASON (the kernel lacks the sch_netem module)"
        return 1
    fi
}

if [[ $MODE == cleanup ]]; then
    valid_prefix "$CLEANUP_PREFIX" || die "--cleanup needs a prefix of [a-z0-9-] (got '$CLEANUP_PREFIX')"
    [[ $(id -u) -eq 0 ]] || die "--cleanup must run as root"
    found=$(run_namespaces "$CLEANUP_PREFIX" | tr '\n' ' ')
    remove_namespaces "$CLEANUP_PREFIX"
    say "removed namespaces: ${found:-none}"
    exit 0
fi

if [[ $MODE == check ]]; then
    trap check_cleanup EXIT
    trap 'exit 130' INT
    trap 'exit 143' TERM
    if ! namespaces_usable "${PREFIX:-tw-$$-$RANDOM}-chk"; then
        echo "namespaces: unusable: $REASON"
        echo "netem: unusable: no namespaces to test it in"
        exit 77
    fi
    echo "namespaces: usable (ip netns, veth pairs, bridge)"
    if netem_usable; then
        echo "netem: usable"
    else
        echo "netem: unusable: $REASON"
        ((WANT_NETEM == 0)) || exit 77
    fi
    exit 0
fi

# --- Run a wall --------------------------------------------------------------------------------

[[ $WALL =~ ^([1-9][0-9]*)x([1-9][0-9]*)$ ]] || die "--wall must be COLUMNSxROWS, e.g. 2x2 (got '$WALL')"
DISPLAYS=$((BASH_REMATCH[1] * BASH_REMATCH[2]))
[[ $SCREEN =~ ^[1-9][0-9]*x[1-9][0-9]*$ ]] || die "--screen must be WIDTHxHEIGHT (got '$SCREEN')"
is_uint "$BEZEL" || die "--bezel must be a whole number of pixels"
if ! is_uint "$FRAMES" || ((FRAMES < 1)); then die "--frames must be at least 1 (the run must end)"; fi
if ! is_uint "$RENDER_NODES" || ((RENDER_NODES < 1 || RENDER_NODES > 90)); then
    die "--render-nodes must be 1..90 (addresses .10-.99)"
fi
((DISPLAYS <= 100)) || die "at most 100 displays (addresses .100-.199), the wall has $DISPLAYS"
if ! is_uint "$TIMEOUT" || ((TIMEOUT < 1)); then die "--timeout must be whole seconds"; fi
if ! [[ $SUBNET =~ ^([0-9]{1,3})\.([0-9]{1,3})\.([0-9]{1,3})$ ]] \
    || ((BASH_REMATCH[1] > 255 || BASH_REMATCH[2] > 255 || BASH_REMATCH[3] > 255)); then
    die "--subnet must be the first three octets of a /24, e.g. 10.77.0 (got '$SUBNET')"
fi
if [[ -z $THREADS ]]; then
    THREADS=$(($(nproc) / RENDER_NODES))
    ((THREADS >= 1)) || THREADS=1
fi
if ! is_uint "$THREADS" || ((THREADS < 1)); then die "--threads must be at least 1"; fi
PREFIX=${PREFIX:-tw-$$-$RANDOM}
valid_prefix "$PREFIX" || die "--prefix must be 2-24 characters of [a-z0-9-], starting with a letter"

if [[ -z $BIN_DIR ]]; then
    target=${CARGO_TARGET_DIR:-$REPO/target}
    for BIN_DIR in "$target/release" "$target/debug" ""; do
        [[ -n $BIN_DIR && -x $BIN_DIR/tessera-master && -x $BIN_DIR/tessera-render-node \
            && -x $BIN_DIR/tessera-display-node ]] && break
    done
    [[ -n $BIN_DIR ]] || die "no tessera binaries in $target/release or $target/debug: run 'cargo build --release' or pass --bin-dir"
fi
for b in tessera-master tessera-render-node tessera-display-node; do
    [[ -x $BIN_DIR/$b ]] || die "$BIN_DIR/$b is missing or not executable (--bin-dir)"
done
BIN_DIR=$(cd "$BIN_DIR" && pwd)

if [[ $(id -u) -eq 0 ]] && command -v ip >/dev/null && [[ -n $(run_namespaces "$PREFIX") ]]; then
    die "namespaces with prefix $PREFIX exist already (a killed run?): remove them with $0 --cleanup $PREFIX"
fi

# From here on everything made is undone by `cleanup`, on any exit.
PIDS=() NAMES=() WORK="" MASTER_PID="" NAP_PID=""
# nap SECONDS: a sleep that a trapped signal interrupts at once (a foreground `sleep` would
# delay the trap until it ends, and `kill -INT` to this script alone would never reach it).
nap() {
    sleep "$1" &
    NAP_PID=$!
    wait "$NAP_PID" || true
    NAP_PID=""
}
alive() {
    # A zombie (exited, not yet reaped) is not alive.
    [[ -r /proc/$1/stat ]] && [[ $(sed 's/.*) //' "/proc/$1/stat" 2>/dev/null | cut -d' ' -f1) != Z ]]
}

# term_and_wait TENTHS PID...: SIGTERM to those alive, then up to TENTHS x 0.1 s for them to exit.
# shellcheck disable=SC2317 # called from the EXIT trap
term_and_wait() {
    local tenths=$1 pid i any
    shift
    for pid in "$@"; do
        [[ -z $pid ]] || ! alive "$pid" || kill -TERM "$pid" 2>/dev/null
    done
    for ((i = 0; i < tenths; i++)); do
        any=0
        for pid in "$@"; do
            [[ -z $pid ]] || ! alive "$pid" || any=1
        done
        ((any)) || return 0
        sleep 0.1
    done
}

# The master first (up to 5 s: it stops the wall and writes report.json with what it has), then
# the nodes (up to 5 s), then SIGKILL to anything left; every child is reaped.
# shellcheck disable=SC2317 # called from the EXIT trap
stop_processes() {
    local pid
    ((${#PIDS[@]})) || return 0
    term_and_wait 50 "${PIDS[0]}"
    term_and_wait 50 "${PIDS[@]}"
    for pid in "${PIDS[@]}"; do
        [[ -n $pid ]] || continue
        ! alive "$pid" || kill -KILL "$pid" 2>/dev/null
        wait "$pid" 2>/dev/null
    done
    PIDS=()
}

# shellcheck disable=SC2317 # the EXIT trap
cleanup() {
    local rc=$?
    trap - EXIT INT TERM HUP
    set +e
    if [[ -n $NAP_PID ]]; then kill "$NAP_PID" 2>/dev/null; wait "$NAP_PID" 2>/dev/null; fi
    stop_processes
    check_cleanup
    local left
    left=$(run_namespaces "$PREFIX" | tr '\n' ' ')
    if ((KEEP)) && [[ -n $left ]]; then
        say "--keep: left namespaces ${left}and certificates in $WORK; remove them with:"
        say "    $0 --cleanup $PREFIX; rm -r $WORK"
    else
        remove_namespaces "$PREFIX"
        [[ -z $WORK ]] || rm -rf "$WORK"
        left=$(run_namespaces "$PREFIX" | tr '\n' ' ')
        [[ -z $left ]] || say "warning: namespaces left: $left"
    fi
    exit "$rc"
}
trap cleanup EXIT
trap 'say "interrupted"; exit 130' INT
trap 'say "terminated"; exit 143' TERM
trap 'exit 129' HUP

namespaces_usable "$PREFIX-chk" || skip "namespaces are unusable: $REASON"
if ((WANT_NETEM)) && ! netem_usable; then
    skip "--delay/--loss need netem, which is unusable: $REASON; not running without it"
fi
check_cleanup

if [[ -z $OUT ]]; then
    OUT=$(mktemp -d "${TMPDIR:-/tmp}/netns-wall.XXXXXX")
fi
mkdir -p "$OUT/logs"
OUT=$(cd "$OUT" && pwd)
rm -f "$OUT/report.json"
WORK=$(mktemp -d "${TMPDIR:-/tmp}/netns-wall-certs.XXXXXX")

# --- Network: a bridge in PREFIX-hub, a veth from it into each node's namespace -----------------
# must COMMAND...: runs COMMAND or dies naming it and its error.
must() { try "$*" "$@" || die "network setup failed: $REASON"; }

HUB=$PREFIX-hub
must ip netns add "$HUB"
must ip -n "$HUB" link add br0 type bridge
must ip -n "$HUB" link set br0 up
must ip -n "$HUB" link set lo up

NETEM=()
[[ -z $DELAY ]] || NETEM+=(delay "${DELAY}ms")
[[ -z $LOSS ]] || NETEM+=(loss "${LOSS}%")

# add_node NAME HOST-OCTET: namespace PREFIX-NAME with eth0 at SUBNET.HOST/24, whose veth peer
# is vNAME on the hub's bridge; netem, if asked for, on eth0 (what the node sends).
add_node() {
    local ns=$PREFIX-$1 addr=$SUBNET.$2
    must ip netns add "$ns"
    must ip -n "$HUB" link add "v$1" type veth peer name eth0 netns "$ns"
    must ip -n "$HUB" link set "v$1" master br0
    must ip -n "$HUB" link set "v$1" up
    must ip -n "$ns" link set lo up
    must ip -n "$ns" addr add "$addr/24" dev eth0
    must ip -n "$ns" link set eth0 up
    if ((${#NETEM[@]})); then
        must ip netns exec "$ns" tc qdisc add dev eth0 root netem "${NETEM[@]}"
    fi
}

MASTER_IP=$SUBNET.1
MASTER_ADDR=$MASTER_IP:7400
add_node m 1
for ((i = 0; i < RENDER_NODES; i++)); do add_node "r$i" $((10 + i)); done
for ((i = 0; i < DISPLAYS; i++)); do add_node "d$i" $((100 + i)); done

# --- Certificates ------------------------------------------------------------------------------
CLUSTER=$WORK/cluster
# issue NAME ROLE-ARGS...: a certificate bound to its role (and a display's to its id).
issue() {
    local name=$1
    shift
    "$BIN_DIR/tessera-master" issue-cert --cluster-dir "$CLUSTER" --name "$name" --out "$WORK/$name" \
        "$@" >>"$OUT/logs/issue-cert.log" 2>&1 || die "issue-cert $name failed: see $OUT/logs/issue-cert.log"
}
for ((i = 0; i < RENDER_NODES; i++)); do issue "render-$i" --role render; done
for ((i = 0; i < DISPLAYS; i++)); do issue "display-$i" --role display --display "$i"; done

# start NAME NAMESPACE COMMAND...: runs COMMAND in NAMESPACE, output to OUT/logs/NAME.log.
# `ip netns exec` execs the command, so the PID is the node's own.
start() {
    local name=$1 ns=$2
    shift 2
    ip netns exec "$ns" "$@" </dev/null >"$OUT/logs/$name.log" 2>&1 &
    PIDS+=($!)
    NAMES+=("$name")
}

netem_text="no netem"
((${#NETEM[@]} == 0)) || netem_text="netem ${NETEM[*]} on every node's link"
say "$WALL wall of $SCREEN, $RENDER_NODES render node(s) x $THREADS thread(s), $FRAMES frames, $netem_text"
say "namespaces $PREFIX-{hub,m,r0..,d0..}, master at $MASTER_ADDR, logs in $OUT/logs"

start master "$PREFIX-m" "$BIN_DIR/tessera-master" serve --listen "$MASTER_ADDR" \
    --cluster-dir "$CLUSTER" --wall "$WALL" --screen "$SCREEN" --bezel "$BEZEL" \
    --scene "$SCENE" --render-nodes "$RENDER_NODES" --frames "$FRAMES" --out "$OUT" \
    --join-timeout "$(((TIMEOUT < 60) ? TIMEOUT : 60))"
MASTER_PID=${PIDS[0]}
DEADLINE=$((SECONDS + TIMEOUT))

# The master's UDP socket is bound before the nodes start (bounded by --timeout).
if command -v ss >/dev/null; then
    until ip netns exec "$PREFIX-m" ss -H -uln "sport = :7400" 2>/dev/null | grep -q .; do
        alive "$MASTER_PID" || { tail -n 20 "$OUT/logs/master.log" >&2; die "the master exited before listening"; }
        ((SECONDS < DEADLINE)) || { say "timed out waiting for the master to listen"; exit 124; }
        nap 0.1
    done
else
    nap 1
fi

for ((i = 0; i < DISPLAYS; i++)); do
    addr=$SUBNET.$((100 + i)):7401
    start "display-$i" "$PREFIX-d$i" "$BIN_DIR/tessera-display-node" --master "$MASTER_ADDR" \
        --display "$i" --cert-dir "$WORK/display-$i" --listen "$addr" --advertise "$addr" --out "$OUT"
done
for ((i = 0; i < RENDER_NODES; i++)); do
    start "render-$i" "$PREFIX-r$i" "$BIN_DIR/tessera-render-node" --master "$MASTER_ADDR" \
        --cert-dir "$WORK/render-$i" --threads "$THREADS"
done

# --- Wait for the master (bounded), then for the nodes to leave on their own --------------------
while alive "$MASTER_PID"; do
    if ((SECONDS >= DEADLINE)); then
        say "timed out after ${TIMEOUT}s; last lines of the master's log:"
        tail -n 20 "$OUT/logs/master.log" >&2
        exit 124
    fi
    nap 0.2
done
master_rc=0
wait "$MASTER_PID" || master_rc=$?
PIDS[0]=""
if ((master_rc != 0)); then
    say "the master failed (exit $master_rc); last lines of its log:"
    tail -n 30 "$OUT/logs/master.log" >&2
    exit 1
fi

node_failures=()
for ((k = 1; k < ${#PIDS[@]}; k++)); do
    pid=${PIDS[k]} name=${NAMES[k]} rc=0
    for ((i = 0; i < 100; i++)); do alive "$pid" || break; nap 0.1; done
    if alive "$pid"; then
        kill -KILL "$pid" 2>/dev/null || true
        wait "$pid" 2>/dev/null || true
        node_failures+=("$name was still running 10 s after the master finished (killed)")
    else
        wait "$pid" || rc=$?
        ((rc == 0)) || node_failures+=("$name exited with $rc (see $OUT/logs/$name.log)")
    fi
    PIDS[k]=""
done

# --- Summary -----------------------------------------------------------------------------------
REPORT=$OUT/report.json
[[ -s $REPORT ]] || die "the master finished but wrote no $REPORT"
command -v python3 >/dev/null || die "python3 is needed to summarize $REPORT"
summary_rc=0
python3 - "$REPORT" "$SUBNET" <<'EOF' || summary_rc=$?
import json, sys

report = json.load(open(sys.argv[1]))
subnet = sys.argv[2]
frames = report["frames"]

def pct(name):
    v = report.get(name)
    if v is None:
        return f"{name}: not in this build"
    if isinstance(v, dict):
        return f"{name}: " + ", ".join(
            f"{k} {x:.2f}" if isinstance(x, (int, float)) else f"{k} {x}" for k, x in v.items()
        )
    return f"{name}: {v}"

print(f"frames {frames} in {report['elapsed_s']:.2f} s: {report['fps']:.1f} fps")
for key in ("frame_ms", "start_to_present_ms", "latency_ms", "skew_ms"):
    print(pct(key))
ok = True
for d in report["displays"]:
    presented = d["frames_presented"]
    ok &= presented == frames
    print(
        f"display {d['id']} ({subnet}.{100 + d['id']}): {presented}/{frames} frames presented, "
        f"{d['wire_bytes_received']} wire bytes ({d['wire_bytes_per_pixel_byte']:.4f} per pixel byte)"
    )
for r in report["render_nodes"]:
    print(f"render node {r['id']} ({r['host']}, {r['cores']} cores): {r['rays_per_s'] / 1e6:.2f} Mrays/s")
print(f"render nodes lost: {report['render_nodes_lost']}")
if not ok:
    print("NOT every display presented every frame", file=sys.stderr)
    sys.exit(1)
print("every display presented every frame")
EOF
say "report: $REPORT"
for f in "${node_failures[@]}"; do say "node failure: $f"; done
((summary_rc == 0)) || exit 1
((${#node_failures[@]} == 0)) || exit 1
exit 0
