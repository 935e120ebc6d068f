#!/usr/bin/env bash
# The value of sharing the grid between robots of different goals: 16 robots on one shared grid
# (random-32-32-10, the first 16 pairs of random-1.scen, each its own goal), 300 episodes,
# `--share hints` (a planning robot adds the moves named in other goals' merged hints to its
# model) against `--share none`, for each seed of $SEEDS (default "1 2 3"). Env steps summed over
# robots until each robot's greedy path was optimal (`steps_to_optimal` of
# robot-<id>-phase-0.json); a robot never optimal counts with every step it took (a lower bound
# of its steps to the optimum), and how many there were is printed.
#
#   cargo build --release --bins && docs/bench/grid-sharing.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-target/release}
M=../shared/data/movingai
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
read -r -a seeds <<< "${SEEDS:-1 2 3}"
echo "| seed | sharing nothing (never optimal) | sharing the grid's moves (never optimal) | ratio |"
echo "|---:|---:|---:|---:|"
for seed in "${seeds[@]}"; do
  for s in none hints; do
    "$BIN/qfleet" run --world shared --map "$M/random-32-32-10.map" \
      --scen "$M/random-32-32-10-random-1.scen" --agents 16 --episodes 300 --seed "$seed" \
      --share "$s" --out "$out/$seed-$s" --force --json > /dev/null 2>&1 || true
  done
  python3 - "$out/$seed-none" "$out/$seed-hints" "$seed" <<'PY'
import glob, json, sys
def total(d):
    steps, never = 0, 0
    for f in glob.glob(f"{d}/robot-*-phase-0.json"):
        r = json.load(open(f))
        if r.get("steps_to_optimal") is None:
            never += 1
            steps += r["env_steps"]
        else:
            steps += r["steps_to_optimal"]
    return steps, never
(a, na), (b, nb) = total(sys.argv[1]), total(sys.argv[2])
print(f"| {sys.argv[3]} | {a:,} ({na}) | {b:,} ({nb}) | {b / a:.2f} |".replace(",", " "))
PY
done
