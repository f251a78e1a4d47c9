#!/usr/bin/env bash
# Builds every fuzz target (cargo-fuzz, libFuzzer, no sanitizer: the stable toolchain has none)
# and runs each in turn on its committed corpus, one job at a time.
set -euo pipefail

usage() {
    cat <<'USAGE'
usage: fuzz/run.sh [--time SECONDS | --runs N] [--seeds] [TARGET...]

  (default)     smoke run: every target for 2 s (under a minute in all), as CI runs it
  --time S      run each target for S seconds
  --runs N      run each target for N executions (the long run: --runs 1000000)
  --seeds       rewrite fuzz/corpus/ from examples/seeds.rs first
  TARGET...     only these targets (default: all, see `cargo fuzz list`)

Runs on the committed corpus in a scratch copy, so new inputs never touch fuzz/corpus/ (to
keep some, `cargo fuzz cmin` and copy them in by hand). Prints executions, exec/s and the
outcome per target; exits non-zero if any target crashed, leaked into a timeout or ran out of
memory, with the input in fuzz/artifacts/<target>/. Reproduce one with
`cargo fuzz run --sanitizer none TARGET fuzz/artifacts/TARGET/crash-...`.
Builds and fuzzes under `nice`; set FUZZ_NICE=0 to run at normal priority.
USAGE
}

cd "$(dirname "$0")"
# The smoke run is seeded: the same binary explores the same inputs on every CI run, so CI
# fails on a regression, not on the luck of the draw (new finds are the long run's job).
limit=(-max_total_time=2 -seed=1)
seeds=false
targets=()
while [ $# -gt 0 ]; do
    case "$1" in
        -h|--help) usage; exit 0 ;;
        --time) limit=(-max_total_time="$2"); shift ;;
        --runs) limit=(-runs="$2"); shift ;;
        --seeds) seeds=true ;;
        -*) echo "fuzz/run.sh: unknown option $1" >&2; usage >&2; exit 2 ;;
        *) targets+=("$1") ;;
    esac
    shift
done
nice=(nice -n "${FUZZ_NICE:-15}")

if ! command -v cargo-fuzz >/dev/null; then
    echo "fuzz/run.sh: cargo-fuzz is missing: cargo install cargo-fuzz --locked" >&2
    exit 2
fi
if $seeds; then
    rm -rf corpus
    "${nice[@]}" cargo run -q --example seeds --target-dir target/seeds -- corpus
fi
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cargo fuzz list)
fi
"${nice[@]}" cargo fuzz build --sanitizer none -O

# Loaders that take paths write their inputs here; removed on the way out.
# On tmpfs where there is one: on disk, the file writes cost the loader targets 5-20x in sys time.
if [ -d /dev/shm ] && [ -w /dev/shm ]; then
    scratch=$(mktemp -d -p /dev/shm)
else
    scratch=$(mktemp -d)
fi
trap 'rm -rf "$scratch"' EXIT
bin=target/x86_64-unknown-linux-gnu/release
failed=()
start=$SECONDS
printf '%-18s %12s %9s %8s  %s\n' target executions exec/s seconds result
for t in "${targets[@]}"; do
    mkdir -p "$scratch/corpus/$t" "artifacts/$t"
    cp corpus/"$t"/* "$scratch/corpus/$t/" 2>/dev/null || true
    log="$scratch/$t.log"
    t0=$(date +%s%N)
    # -rss_limit_mb and -timeout turn a huge allocation or a hang into a finding.
    status=0
    TMPDIR="$scratch" "${nice[@]}" "$bin/$t" "${limit[@]}" -rss_limit_mb=2048 -timeout=10 \
        -artifact_prefix="artifacts/$t/" -print_final_stats=1 "$scratch/corpus/$t" \
        >"$log" 2>&1 || status=$?
    if [ $status -eq 0 ]; then
        result=ok
    else
        why=$(grep -m1 -oE 'ERROR: libFuzzer: [a-z-]+|panicked at [^ ]+' "$log" || echo "exit $status")
        result="FAILED ($why)"
        failed+=("$t")
        tail -40 "$log" >&2
    fi
    # From the wall clock in ms: libFuzzer's own exec/s rounds runs under a second to 0.
    ms=$(( ($(date +%s%N) - t0) / 1000000 ))
    runs=$(grep -oE 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -oE '[0-9]+$' || echo 0)
    printf '%-18s %12s %9s %8s  %s\n' "$t" "$runs" "$((runs * 1000 / (ms > 0 ? ms : 1)))" \
        "$((ms / 1000)).$((ms % 1000 / 100))" "$result"
done
echo "all targets: $((SECONDS - start)) s"
if [ ${#failed[@]} -gt 0 ]; then
    echo "fuzz/run.sh: crashed: ${failed[*]} (inputs in fuzz/artifacts/)" >&2
    exit 1
fi
