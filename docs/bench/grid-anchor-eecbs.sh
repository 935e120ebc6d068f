#!/usr/bin/env bash
# EECBS (Li, Ruml and Koenig, AAAI 2021: bounded-suboptimal conflict-based search, C++) on the
# crowded held-out instances of grid-quality.sh, as an outside anchor for what the optimum can
# be. Each run gives two numbers over the same lower bound as the fleet's (the sum of
# single-robot distances): EECBS's *proven* lower bound on the optimal sum of costs (its
# "min f value", valid even when it times out) and the sum of costs of the solution it found,
# if any, within `w` times the optimum. The optimum lies between them. Suboptimality bounds
# are tried in turn (W) until one finds a solution within T seconds.
#
# Build EECBS once (it is not a dependency of qfleet; needs Boost and cmake:
#   apt-get install -y cmake libboost-program-options-dev libboost-system-dev libboost-filesystem-dev
#   git clone https://github.com/Jiaoyang-Li/EECBS && cd EECBS && cmake -DCMAKE_BUILD_TYPE=RELEASE . && make eecbs
# then, from this repository's root:
#   EECBS=path/to/EECBS/eecbs docs/bench/grid-anchor-eecbs.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
: "${EECBS:?set EECBS to a built EECBS binary (see the header)}"
T=${T:-120}
W=${W:-1.01 1.05 1.10}
N=${N:-48}
MAPS=${MAPS:-maze-32-32-2 room-32-32-4}
SEEDS=${SEEDS:-1 2}
M=../shared/data/movingai
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "EECBS, ${T} s a run, $(date -u '+%Y-%m-%d %H:%M UTC')"
echo
echo "| instance | agents | LB | EECBS lower bound / LB | EECBS SoC / LB | w | s |"
echo "|---|---:|---:|---:|---:|---:|---:|"
for map in $MAPS; do
  for seed in $SEEDS; do
    python3 docs/bench/random-scen.py "$M/$map.map" "$N" "$seed" > "$out/s.scen"
    best=0 lb=0 soc=-1 used=- secs=-
    for w in $W; do
      rm -f "$out/r.csv"
      "$EECBS" -m "$M/$map.map" -a "$out/s.scen" -o "$out/r.csv" -k "$N" -t "$T" \
        --suboptimality="$w" > /dev/null 2>&1 || true
      [ -s "$out/r.csv" ] || continue
      # runtime, ..., solution cost (6th), min f value (7th), root g value = the bound (8th)
      IFS=, read -r secs _ _ _ _ soc minf lb _ < <(tail -1 "$out/r.csv")
      used=$w
      if [ "${minf%.*}" -gt "$best" ]; then best=${minf%.*}; fi
      if [ "$soc" -ge 0 ]; then break; fi
    done
    python3 - "$map seed $seed (held out)" "$N" "$lb" "$best" "$soc" "$used" "$secs" <<'PY'
import sys
name, n, lb, best, soc, w, secs = sys.argv[1:]
lb, best, soc = int(lb), int(best), int(soc)
if lb <= 0:
    print(f"| {name} | {n} | failed | | | | |"); sys.exit()
found = f"{soc / lb:.3f}" if soc >= 0 else "none"
print(f"| {name} | {n} | {lb} | {best / lb:.3f} | {found} | {w} | {float(secs):.0f} |")
PY
  done
done
