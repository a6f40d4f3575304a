#!/usr/bin/env bash
# False names: `explain` from nothing on clean machines (the default and the 32 kg plant
# file) over five measurement grids a lab might choose, two seeds each; one line per run with
# every rung's held-out error before and after and why the ladder stopped.
#   bash bench/false-names.sh [STS_TWIN]   (STS_TWIN: the binary, default `sts-twin` on PATH)
#   PLANTS="default" GRIDS="from10 nine" SEEDS="1 2 3" bash bench/false-names.sh
set -euo pipefail
bin=${1:-sts-twin}
root=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
grids=(
    "paper|1,5,10,15,20,25,30,35,40|1,2,3,4,5,6,7,8,9,10,11"
    "from5|5,10,15,20,25,30,35,40|2,4,6,8,10"
    "from10|10,20,30,40,50,60,70,80,90,100|1,3,5,7,9,11"
    "wide|1,5,10,15,20,25,30,35,40,45,50,55,60,65,70,75,80,85,90,95,100|1,2,3,4,5,6,7,8,9,10,11"
    "nine|5,10,20|2,6,10"
)
for plant in ${PLANTS:-default slide-32kg}; do
    plant_args=()
    [ "$plant" != default ] && plant_args=(--plant "$root/host-tools/assess/tests/plants/$plant.toml")
    for grid in "${grids[@]}"; do
        IFS='|' read -r name freqs amps <<<"$grid"
        case " ${GRIDS:-paper from5 from10 wide nine} " in *" $name "*) ;; *) continue ;; esac
        for seed in ${SEEDS:-1 2}; do
            data=$work/data
            rm -rf "$data"
            if ! log=$("$bin" measure --out "$data" --freqs "$freqs" --amps "$amps" --seed "$seed" --quiet "${plant_args[@]}" 2>&1); then
                echo "$log" >&2
                exit 1
            fi
            start=$(date +%s.%N)
            rm -f "$work/twin.json"
            "$bin" explain "$data" --out "$work/twin.json" --json 2>/dev/null >"$work/ladder.json"
            end=$(date +%s.%N)
            python3 - "$plant" "$name" "$seed" "$work/ladder.json" "$start" "$end" <<'P'
import json, sys
plant, grid, seed, path, start, end = sys.argv[1:]
ladder = json.load(open(path))
rungs = "; ".join(
    f"{s['effect']} {s['waveform_rms_um_before'] * 1e3:.1f} -> {s['waveform_rms_um_after'] * 1e3:.1f} nm "
    f"({(1 - s['waveform_rms_um_after'] / s['waveform_rms_um_before']) * 100:.0f}%)"
    for s in ladder["steps"]
) or "nothing named"
print(f"{plant:<10} {grid:<6} seed {seed}: {float(end) - float(start):5.1f} s, "
      f"{ladder['start_waveform_rms_um'] * 1e3:7.1f} nm: {rungs}; stop {ladder['verdict']}")
P
        done
    done
done
