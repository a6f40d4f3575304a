#!/usr/bin/env bash
# Runs the full statistical suites that BENCHMARKS.md quotes, all at one commit, and keeps each
# suite's printed tables in target/suites/COMMIT/NAME.txt, headed by the commit, the date, the
# machine and the settings:
#
#   reference   diagnose_hidden_effects::full_suite, the clean machine's twin, 20 seeds per
#               effect, 3 of them refitted, the paper's 99 groups;
#   lab         the same in the lab's workflow (a twin fitted on each case's own data), every
#               seed refitted;
#   sets        explain_several_effects::full_sets, every pair of effects and 10 triples, 5
#               seeds, the paper's groups.
#
#   scripts/full-suites.sh [NAME...]          (default: all three, in that order; hours each)
#
# The work tree must be clean, so that every figure is the commit's. A variable the suites
# read (STS_SUITE_*, STS_SETS_*, STS_PLANT; see each test's module docs) set in the
# environment overrides the settings above and is written in the header.
set -euo pipefail
cd "$(dirname "$0")/.."
suites=("$@")
[ ${#suites[@]} -gt 0 ] || suites=(reference lab sets)
for name in "${suites[@]}"; do
    case "$name" in
        reference | lab | sets) ;;
        *) echo "error: no suite named '$name' (reference, lab, sets)" >&2; exit 2 ;;
    esac
done
if [ -n "$(git status --porcelain --untracked-files=no)" ]; then
    echo "error: the work tree has changes: commit them first, so that the figures are one commit's" >&2
    exit 1
fi
commit=$(git rev-parse --short=12 HEAD)
out=target/suites/$commit
mkdir -p "$out"
# Built first, so that each table file holds the suite's output, not the build's.
cargo build --locked --release -p sts-assess --tests

run() {
    local name=$1 test=$2
    shift 2
    local file="$out/$name.txt" partial="$out/.$name.txt.partial"
    # The suite's settings: these defaults, unless the caller's environment sets them.
    local settings=() setting key
    for setting in "$@"; do
        key=${setting%%=*}
        settings+=("$key=${!key:-${setting#*=}}")
    done
    local from_env
    from_env=$(env | grep -oE '^(STS_SUITE_|STS_SETS_|STS_PLANT)[A-Z_]*=' | tr -d '=' | sort | tr '\n' ' ' || true)
    {
        echo "# $name: $test"
        echo "# commit $(git rev-parse HEAD), $(date -u +%Y-%m-%dT%H:%M:%SZ), $(nproc) cores, $(uname -m)"
        echo "# settings: ${settings[*]}${from_env:+ (set in the environment: $from_env)}"
    } >"$partial"
    echo "== $name -> $file (started $(date -u +%H:%M:%S))"
    env "${settings[@]}" cargo test --locked --release -p sts-assess --test tests "$test" -- --ignored --nocapture \
        >>"$partial" 2>&1 || { echo "error: $name failed; its output so far: $partial" >&2; return 1; }
    mv "$partial" "$file"
}

status=0
for name in "${suites[@]}"; do
    case "$name" in
        reference) run reference diagnose_hidden_effects::full_suite \
            STS_SUITE_SEEDS=20 STS_SUITE_FIT_SEEDS=3 STS_SUITE_GRID=paper || status=1 ;;
        lab) run lab diagnose_hidden_effects::full_suite \
            STS_SUITE_WORKFLOW=lab STS_SUITE_SEEDS=20 STS_SUITE_FIT_SEEDS=20 STS_SUITE_GRID=paper || status=1 ;;
        sets) run sets explain_several_effects::full_sets \
            STS_SETS_SEEDS=5 STS_SETS_TRIPLES=10 STS_SETS_GRID=paper || status=1 ;;
    esac
done
echo "tables in $out"
exit "$status"
