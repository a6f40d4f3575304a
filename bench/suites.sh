#!/usr/bin/env bash
# The full suites at the checked-out commit, every table BENCHMARKS.md quotes from them in one
# run: the hidden-effect suite in both workflows (20 seeds, refits on 3), the several-effects
# sets (every pair and 10 triples, 5 seeds), on the default machine and on the 32 kg plant
# file, and the false-name ladders on clean machines. Hours on 2 cores; each part's output goes
# to its own log in OUT (default: suites-<commit>), headed by the commit and the date.
#   bash bench/suites.sh [OUT]
#   PARTS="lab sets" bash bench/suites.sh      # some parts only: reference lab sets false-names
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
commit=$(git rev-parse --short HEAD)
out=${1:-suites-$commit}
mkdir -p "$out"
header() { printf '# %s at %s%s, %s\n' "$1" "$commit" "$(git diff --quiet HEAD || echo ' (with uncommitted changes)')" "$(date -u +%Y-%m-%dT%H:%MZ)"; }
cargo build --locked --release -p sts-twin
cargo test --locked --release -p sts-assess --test tests --no-run
run_suite() {
    local name=$1 filter=$2
    shift 2
    for plant in default slide-32kg; do
        local log="$out/$name-$plant.txt"
        local plant_env=()
        [ "$plant" != default ] && plant_env=(STS_PLANT="host-tools/assess/tests/plants/$plant.toml")
        header "$name on the $plant machine" >"$log"
        echo "== $name, $plant machine -> $log"
        env "${plant_env[@]}" "$@" cargo test --locked --release -p sts-assess --test tests "$filter" \
            -- --ignored --nocapture --test-threads=1 >>"$log" 2>&1 || echo "   $name on $plant: FAILED (see $log)"
    done
}
for part in ${PARTS:-reference lab sets false-names}; do
    case $part in
        reference) run_suite reference diagnose_hidden_effects::full_suite \
            STS_SUITE_SEEDS=20 STS_SUITE_FIT_SEEDS=3 STS_SUITE_GRID=paper ;;
        lab) run_suite lab diagnose_hidden_effects::full_suite \
            STS_SUITE_WORKFLOW=lab STS_SUITE_SEEDS=20 STS_SUITE_FIT_SEEDS=3 STS_SUITE_GRID=paper ;;
        sets) run_suite sets explain_several_effects::full_sets \
            STS_SETS_SEEDS=5 STS_SETS_TRIPLES=10 STS_SETS_GRID=paper ;;
        false-names)
            header "false names on clean machines" >"$out/false-names.txt"
            echo "== false names -> $out/false-names.txt"
            SEEDS="1 2 3 4 5 6 7 8 9 10" bash bench/false-names.sh target/release/sts-twin >>"$out/false-names.txt" ;;
        *) echo "unknown part $part (reference, lab, sets, false-names)" >&2; exit 2 ;;
    esac
done
echo "logs in $out"
