#!/usr/bin/env bash
# LaCAM3 (Okumura, AAMAS 2024: the field's anytime MAPF planner, C++) on the instances of
# grid-quality.sh, as an outside anchor for the shared grid's sum of costs. LaCAM3 refines the
# sum of *loss* (moves and waits off the goal); the shared grid is judged, as POGEMA and
# mapf-visualizer count it, on the sum of *costs* (ticks until each robot reaches its goal and
# stays): both are printed, over the same lower bound (the sum of single-robot distances).
#
# Build LaCAM3 once (it is not a dependency of qfleet; needs network or a copy of both repos):
#   git clone --recursive https://github.com/Kei18/lacam3 && cd lacam3
#   g++ -O3 -std=c++17 -Ilacam3/include -Ithird_party/argparse/include main.cpp lacam3/src/*.cpp -o main -lpthread
# then, from this repository's root:
#   LACAM3=path/to/lacam3/main T=10 docs/bench/grid-anchor-lacam3.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
: "${LACAM3:?set LACAM3 to a built LaCAM3 binary (see the header)}"
T=${T:-10}
M=../shared/data/movingai
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
row() { # map scen agents label
  if ! "$LACAM3" -m "$1" -i "$2" -N "$3" -t "$T" -v 0 -o "$out/r.txt" > /dev/null 2>&1; then
    echo "| $4 | $3 | failed | | | | |"; return
  fi
  python3 - "$out/r.txt" "$4" "$3" <<'PY'
import sys
kv = dict(l.split("=", 1) for l in open(sys.argv[1]).read().splitlines() if "=" in l and ":" not in l.split("=")[0])
soc, lb, loss = int(kv["soc"]), int(kv["soc_lb"]), int(kv["sum_of_loss"])
print(f"| {sys.argv[2]} | {sys.argv[3]} | {kv['solved']} | {soc} | {lb} | {soc / lb:.3f} | {loss / lb:.3f} |")
PY
}
echo "LaCAM3, ${T} s a run, $(date -u '+%Y-%m-%d %H:%M UTC')"
echo
echo "| instance | agents | solved | SoC | LB | SoC/LB | loss/LB |"
echo "|---|---:|---|---:|---:|---:|---:|"
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
