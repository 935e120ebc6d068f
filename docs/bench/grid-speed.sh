#!/usr/bin/env bash
# Shared-grid ticks/s beside POGEMA's bare simulator on the same instance, in one run:
# random-32-32-10, the first N pairs of random-32-32-10-random-1.scen, N = 8 64 128 (or $@);
# each N with every intent horizon of $HORIZONS (default "0 8": one intent per robot and tick,
# then the default horizon), POGEMA once per N.
#
#   python3 -m venv /tmp/pogema-venv && /tmp/pogema-venv/bin/pip install pogema==1.4.0
#   cargo build --release --bins && docs/bench/grid-speed.sh
#
# Needs ../shared (the MovingAI files and POGEMA's envspeed.py); BIN=target/release by default.
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-target/release}
PY=${POGEMA_PYTHON:-/tmp/pogema-venv/bin/python}
M=../shared/data/movingai
A=../shared/anchors/pogema
ns=("${@:-8 64 128}")
# shellcheck disable=SC2206
ns=(${ns[*]})
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
read -r -a horizons <<< "${HORIZONS:-0 8}"
printf '| robots | intent horizon | qfleet ticks/s | tick p50 | resolve p50 | SoC/LB | POGEMA ticks/s | ratio |\n|---:|---:|---:|---:|---:|---:|---:|---:|\n'
for n in "${ns[@]}"; do
  pogema=$(cd "$A" && "$PY" envspeed.py "$OLDPWD/$M/random-32-32-10.map" "$OLDPWD/$M/random-32-32-10-random-1.scen" "$n" \
    | sed -n 's/.*agents: \([0-9]*\) ticks\/s.*/\1/p')
  for h in "${horizons[@]}"; do
    "$BIN/qfleet" run --world shared --map "$M/random-32-32-10.map" \
      --scen "$M/random-32-32-10-random-1.scen" --agents "$n" --episodes 200 \
      --intent-horizon "$h" --out "$out/$n-$h" --json > "$out/$n-$h.json" 2>/dev/null
    python3 - "$out/$n-$h.json" "$n" "$h" "$pogema" <<'PY'
import json, sys
g = json.load(open(sys.argv[1]))["grid"]
n, h, pogema = sys.argv[2], sys.argv[3], float(sys.argv[4])
print(f"| {n} | {h} | {g['ticks_per_s']:.0f} | {g['tick_latency_ns']['p50']/1e3:.0f} µs "
      f"| {g['resolve_latency_ns']['p50']/1e3:.0f} µs | {g['soc_ratio']:.3f} | {pogema:.0f} "
      f"| {g['ticks_per_s']/pogema:.2f} |")
PY
  done
done
