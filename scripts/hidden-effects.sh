#!/usr/bin/env bash
# The check on the machines with hidden effects: for each effect of the library, the
# emulated machine is measured with it (seed 1), a twin refitted with it (`fit --effect`),
# and the bicuspid cut made at 5, 40 and 80 Hz with the core on the host (bit for bit the
# firmware's), without and with the twin. Prints one line per cut; "ok" where the twin's
# cut is within 5% or 10 nm PV of the bare machine's or better. Work files go to $OUT
# (default target/hidden-effects). About 5 min on a 2-core machine.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-target/hidden-effects}
mkdir -p "$OUT"
cargo build --locked --release -q -p sts-twin
BIN=target/release/sts-twin
for effect in coulomb-friction presliding-hysteresis structural-mode loop-delay setpoint-delay thermal-drift \
    force-ripple axis-coupling sensor-gain; do
  "$BIN" measure --effect "$effect" --seed 1 --out "$OUT/$effect" --quiet >/dev/null 2>&1
  "$BIN" fit "$OUT/$effect" --effect "$effect" --out "$OUT/$effect.json" >/dev/null 2>"$OUT/$effect.fit.log"
  "$BIN" trial-table --sim --effect "$effect" --twin "$OUT/$effect.json" --freqs 5,40,80 --json \
    2>/dev/null >"$OUT/$effect.trial.json"
  python3 - "$effect" "$OUT/$effect.trial.json" <<'PY'
import json, sys
effect, path = sys.argv[1], sys.argv[2]
for row in json.load(open(path)):
    bare, twin = row["bare"]["form_error_pv_um"], row["twin"]["form_error_pv_um"]
    verdict = "ok" if twin <= max(1.05 * bare, bare + 0.010) else "WORSE"
    print(f"{effect:22s} {row['bare']['freq_hz']:4.0f} Hz  bare {bare:8.3f} um  twin {twin:8.3f} um  "
          f"{verdict:5s}  compensation {row['compensation']}")
PY
done
