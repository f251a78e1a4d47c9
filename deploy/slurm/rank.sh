#!/usr/bin/env bash
# One task of tessera-wall.sbatch's `srun --multi-prog`: `rank.sh master`, `rank.sh standby`
# (with TESSERA_STANDBY=1), `rank.sh render I` or `rank.sh display ID`. Reads what the batch script exported (TESSERA_BIN, TESSERA_RUN_DIR,
# TESSERA_MASTER_HOST, TESSERA_PORT, ...; see tessera-wall.sbatch) and execs the node, so that
# Slurm's signals reach it directly.
#
# The master writes RUN_DIR/master.addr (HOST:PORT) once it listens; render and display nodes
# wait for that file, at most TESSERA_JOIN_TIMEOUT seconds, then join. If the master exits
# first it writes RUN_DIR/master.failed instead and the nodes give up at once. A standby master
# (`serve --standby-of`) writes RUN_DIR/standby.addr (or standby.failed) the same way, and the
# nodes then join `--master PRIMARY,STANDBY`.
set -euo pipefail

PROG="tessera-wall rank ${SLURM_PROCID:-?}"
die() { echo "$PROG: error: $*" >&2; exit 1; }

for v in TESSERA_BIN TESSERA_RUN_DIR TESSERA_MASTER_HOST TESSERA_PORT TESSERA_JOIN_TIMEOUT; do
    [[ -n ${!v:-} ]] || die "$v is not set: rank.sh runs under tessera-wall.sbatch's srun"
done
RUN=$TESSERA_RUN_DIR

wall_flags() {
    if [[ -n ${TESSERA_WALL_FILE:-} ]]; then
        WALL_FLAGS=(--wall-file "$TESSERA_WALL_FILE")
    else
        WALL_FLAGS=(--wall "$TESSERA_WALL" --screen "$TESSERA_SCREEN" --bezel "$TESSERA_BEZEL")
    fi
}

# alive PID: running, not a zombie.
alive() {
    [[ -r /proc/$1/stat ]] && [[ $(sed 's/.*) //' "/proc/$1/stat" 2>/dev/null | cut -d' ' -f1) != Z ]]
}

# Writes RUN_DIR/$3.addr (HOST $4) once the master (PID $1) logs its address in $2, or
# RUN_DIR/$3.failed if it exits or the time runs out first. Bounded by TESSERA_JOIN_TIMEOUT.
announce() {
    local pid=$1 log=$2 addr=$RUN/$3.addr failed=$RUN/$3.failed host=$4
    local deadline=$((SECONDS + TESSERA_JOIN_TIMEOUT)) line port
    while ((SECONDS < deadline)) && alive "$pid"; do
        if line=$(grep -m 1 'listening on' "$log" 2>/dev/null); then
            port=${line##*:}
            echo "$host:$port" >"$addr.tmp"
            mv "$addr.tmp" "$addr"
            return 0
        fi
        sleep 0.2
    done
    if alive "$pid"; then
        echo "the $3 did not listen within ${TESSERA_JOIN_TIMEOUT}s; see $log" >"$failed"
    else
        echo "the $3 exited before it listened; see $log" >"$failed"
    fi
}

# The HOST:PORT of the master named $1 (master, standby), once it listens (bounded).
address_of() {
    local addr=$RUN/$1.addr failed=$RUN/$1.failed deadline=$((SECONDS + TESSERA_JOIN_TIMEOUT))
    until [[ -s $addr ]]; do
        [[ ! -e $failed ]] || die "$(cat "$failed")"
        ((SECONDS < deadline)) || die "the $1 did not listen within ${TESSERA_JOIN_TIMEOUT}s (no $addr)"
        sleep 0.2
    done
    cat "$addr"
}

# What the nodes give --master: the primary, then the standby if the job has one.
master_address() {
    local masters
    masters=$(address_of master)
    [[ ${TESSERA_STANDBY:-0} != 1 ]] || masters="$masters,$(address_of standby)"
    echo "$masters"
}

# This host's address as the other nodes of the job reach it (its NodeAddr), for the standby.
own_address() {
    local addr=
    if [[ -n ${SLURMD_NODENAME:-} ]]; then
        addr=$(scontrol show node "$SLURMD_NODENAME" 2>/dev/null | sed -n 's/.*NodeAddr=\([^ ]*\).*/\1/p' | head -n 1)
    fi
    echo "${addr:-$(hostname)}"
}

role=${1:-}
case $role in
    master)
        wall_flags
        read -r -a extra <<<"${TESSERA_MASTER_ARGS:-}"
        log=$RUN/logs/master.log
        : >"$log"
        # The announcer is a child of the master once this shell execs it; it ends by itself.
        announce $$ "$log" master "$TESSERA_MASTER_HOST" &
        exec "$TESSERA_BIN" serve --listen "0.0.0.0:$TESSERA_PORT" --cluster-dir "$RUN/cluster" \
            "${WALL_FLAGS[@]}" --scene "$TESSERA_SCENE" --render-nodes "$TESSERA_RENDER_NODES" \
            --frames "$TESSERA_FRAMES" --join-timeout "$TESSERA_JOIN_TIMEOUT" --out "$TESSERA_OUT" \
            "${extra[@]}" 2>"$log"
        ;;
    standby)
        # The primary's run flags; its own --out, so that a standby that took over no wall
        # (cut off from a live primary) never overwrites the primary's report.
        wall_flags
        read -r -a extra <<<"${TESSERA_MASTER_ARGS:-}"
        log=$RUN/logs/standby.log
        : >"$log"
        primary=$(address_of master)
        port=0
        [[ $TESSERA_PORT == 0 ]] || port=$((TESSERA_PORT + 1))
        announce $$ "$log" standby "$(own_address)" &
        exec "$TESSERA_BIN" serve --standby-of "$primary" --listen "0.0.0.0:$port" \
            --cluster-dir "$RUN/cluster" "${WALL_FLAGS[@]}" --scene "$TESSERA_SCENE" \
            --render-nodes "$TESSERA_RENDER_NODES" --frames "$TESSERA_FRAMES" \
            --join-timeout "$TESSERA_JOIN_TIMEOUT" --out "$TESSERA_OUT/standby" \
            "${extra[@]}" 2>"$log"
        ;;
    render)
        index=${2:?rank.sh render needs the render node index}
        read -r -a extra <<<"${TESSERA_RENDER_ARGS:-}"
        threads=${TESSERA_THREADS:-${SLURM_CPUS_PER_TASK:-}}
        thread_flags=()
        [[ -z $threads ]] || thread_flags=(--threads "$threads")
        master=$(master_address)
        exec "$TESSERA_BIN" render-node --master "$master" --cert-dir "$RUN/certs/render-$index" \
            "${thread_flags[@]}" "${extra[@]}"
        ;;
    display)
        id=${2:?rank.sh display needs the display id}
        # --out: where a frame the master asks to save goes (--save-frame in TESSERA_MASTER_ARGS).
        read -r -a extra <<<"${TESSERA_DISPLAY_ARGS:-}"
        port=0
        [[ -z ${TESSERA_DISPLAY_PORT:-} ]] || port=$((TESSERA_DISPLAY_PORT + id))
        master=$(master_address)
        exec "$TESSERA_BIN" display-node --master "$master" --display "$id" \
            --cert-dir "$RUN/certs/display-$id" --listen "0.0.0.0:$port" --out "$TESSERA_OUT" \
            "${extra[@]}"
        ;;
    *) die "usage: rank.sh master | standby | render INDEX | display ID (got '${*}')" ;;
esac
