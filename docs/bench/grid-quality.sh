#!/usr/bin/env bash
# Shared-grid quality end to end (learned intents, real processes): sum of costs over the lower
# bound, all arrived, conflicts. The tuning instance first (random-32-32-10, the first N pairs of
# random-1.scen), then held-out maps with random pairs (docs/bench/random-scen.py, seeds 1 2).
#
#   cargo build --release --bins && docs/bench/grid-quality.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-target/release}
M=../shared/data/movingai
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
row() { # map scen agents label
  "$BIN/qfleet" run --world shared --map "$1" --scen "$2" --agents "$3" --episodes 300 \
    --out "$out/run" --force --json > "$out/r.json" 2>/dev/null || true
  python3 - "$out/r.json" "$4" "$3" <<'PY'
import json, sys
try:
    g = json.load(open(sys.argv[1]))["grid"]
except Exception as e:
    print(f"| {sys.argv[2]} | {sys.argv[3]} | failed: {e} |"); sys.exit()
print(f"| {sys.argv[2]} | {sys.argv[3]} | {g['all_arrived']} | {g['conflicts']} | {g['sum_of_costs']} "
      f"| {g['lower_bound']} | {g['soc_ratio']:.3f} | {g['makespan']} |")
PY
}
echo "| instance | robots | all arrived | conflicts | SoC | LB | SoC/LB | makespan |"
echo "|---|---:|---|---:|---:|---:|---:|---:|"
for n in 8 16 32 64 128; do
  row "$M/random-32-32-10.map" "$M/random-32-32-10-random-1.scen" "$n" "random-32-32-10 random-1 (tuning)"
done
for map in random-64-64-10 room-32-32-4 maze-32-32-2 warehouse-10-20-10-2-1 den312d; do
  for n in 16 48; do
    for seed in 1 2; do
      python3 docs/bench/random-scen.py "$M/$map.map" "$n" "$seed" > "$out/s.scen"
      row "$M/$map.map" "$out/s.scen" "$n" "$map seed $seed (held out)"
    done
  done
done
