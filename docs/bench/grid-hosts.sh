#!/usr/bin/env bash
# Shared-grid ticks/s on one host and across two, in one run: the warehouse instance of
# examples/grid with N agents (default 16), first on this host alone, then with the last K
# (default N/2) on a second "host": two network namespaces joined by a veth pair, each with a
# private tmpfs on /dev/shm and /tmp/iceoryx2 (as tests/multihost.rs makes them), so the
# network is the only path. Needs root, iproute2, util-linux and jq.
#
#   cargo build --bins && sudo BIN=target/debug docs/bench/grid-hosts.sh 16 8
set -euo pipefail
cd "$(dirname "$0")/../.."
BIN=${BIN:-target/release}
N=${1:-16}
K=${2:-$((N / 2))}
Q=$PWD/$BIN/qfleet
M=examples/grid/warehouse.map
S=examples/grid/warehouse.scen
T=$(mktemp -d)
a=qga$$ b=qgb$$
cleanup() { ip netns del "$a" 2>/dev/null || true; ip netns del "$b" 2>/dev/null || true; }
trap cleanup EXIT
grid() { jq -c '.grid | {ended, all_arrived, conflicts, makespan, ticks_per_s}' "$1"; }
date -u
"$Q" run --world shared --map $M --scen $S --agents "$N" --episodes 300 --json --out "$T/one" \
    >"$T/one.json" 2>"$T/one.err"
echo "one host ($N robots): $(grid "$T/one.json")"
ip netns add "$a"
ip netns add "$b"
ip link add "v$a" type veth peer name "v$b"
ip link set "v$a" netns "$a"
ip link set "v$b" netns "$b"
ip -n "$a" addr add 10.78.0.1/24 dev "v$a"
ip -n "$b" addr add 10.78.0.2/24 dev "v$b"
for n in "$a" "$b"; do ip -n "$n" link set lo up; done
ip -n "$a" link set "v$a" up
ip -n "$b" link set "v$b" up
host() {
    local ns=$1
    shift
    ip netns exec "$ns" unshare -m --propagation private sh -c 'mount -t tmpfs q /dev/shm &&
        mkdir -p /tmp/iceoryx2 && mount -t tmpfs i /tmp/iceoryx2 && exec "$0" "$@"' "$@"
}
host "$a" "$Q" run --world shared --map $M --scen $S --agents "$N" --remote-robots "$K" \
    --listen tcp/10.78.0.1:7447 --episodes 300 --json --out "$T/a" >"$T/a.json" 2>"$T/a.err" &
pid=$!
until [ -s "$T/a/join.secret" ]; do sleep 0.1; done
host "$b" "$Q" join tcp/10.78.0.1:7447 --robots "$K" --secret-file "$T/a/join.secret" \
    --out "$T/b" >"$T/b.out" 2>"$T/b.err"
wait "$pid"
echo "two hosts ($((N - K)) + $K robots): $(grid "$T/a.json")"
echo "files in $T"
