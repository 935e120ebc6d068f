#!/usr/bin/env python3
"""Recording overhead: `qfleet run` with and without `--record`, side by side.

Runs the same fleet REPS times each way, alternating (plain, record, plain, record, ...) so
that both see the same machine load, and prints a Markdown table of medians and of the
ratio record / plain for wall time, learning time, message and merge throughput, and CPU time
(user + sys of qfleet and every process it started and waited for).

    docs/bench/record-overhead.py [--bin target/release] [--reps 10] [-- RUN OPTIONS...]

Default run options: --robots 4 --map builtin:paper-30 --episodes 1000.
Only the standard library; the binaries must be built (`cargo build --release --bins`).
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time


def one(bin_dir, opts, record, tmp, i):
    cmd = [os.path.join(bin_dir, "qfleet"), "run", "--json", "--run-id", f"recbench-{os.getpid()}-{i}"]
    cmd += opts
    rec = os.path.join(tmp, f"r{i}.mcap")
    if record:
        cmd += ["--record", rec]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        sys.exit(f"run failed ({p.returncode}): {' '.join(cmd)}\n{p.stderr}")
    r = json.loads(p.stdout)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    size = os.path.getsize(rec) if record else 0
    if record:
        os.remove(rec)
    return {
        "wall_s": wall,
        "active_s": r["throughput"]["active_s"],
        "messages_per_s": r["throughput"]["messages_per_s"],
        "q_merged_per_s": r["throughput"]["q_updates_merged_per_s"],
        "cpu_s": cpu,
        "mcap_bytes": size,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default="target/release", help="directory of the qfleet binaries")
    ap.add_argument("--reps", type=int, default=10, help="runs each way")
    ap.add_argument("opts", nargs="*", help="qfleet run options (after --)")
    a = ap.parse_args()
    if a.reps < 1:
        sys.exit("--reps must be >= 1")
    opts = a.opts or ["--robots", "4", "--map", "builtin:paper-30", "--episodes", "1000"]
    runs = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="qfleet-recbench-") as tmp:
        for i in range(a.reps):
            for record in (False, True) if i % 2 == 0 else (True, False):
                runs[record].append(one(a.bin, opts, record, tmp, 2 * i + record))
    keys = [
        ("wall_s", "wall time, s"),
        ("active_s", "learning time (first to last robot message), s"),
        ("messages_per_s", "messages/s"),
        ("q_merged_per_s", "Q-updates merged/s"),
        ("cpu_s", "CPU time, all processes, s"),
    ]
    print(f"`qfleet run {' '.join(opts)}`, {a.reps} runs each way, alternating; medians (min–max)\n")
    print("| figure | plain | --record | record / plain |")
    print("|---|---:|---:|---:|")
    for k, name in keys:
        p = [r[k] for r in runs[False]]
        q = [r[k] for r in runs[True]]
        mp, mq = statistics.median(p), statistics.median(q)
        ratio = mq / mp if mp else float("nan")
        print(f"| {name} | {mp:.3g} ({min(p):.3g}–{max(p):.3g}) | {mq:.3g} ({min(q):.3g}–{max(q):.3g}) | {ratio:.3f} |")
    size = statistics.median(r["mcap_bytes"] for r in runs[True])
    print(f"\nrecording size: median {size / 1e6:.2f} MB per run")


if __name__ == "__main__":
    main()
