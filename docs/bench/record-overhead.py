#!/usr/bin/env python3
"""Recording overhead: `qfleet run` with and without `--record`, side by side.

Runs the same fleet REPS times each way, alternating (plain, record, plain, record, ...) so
that both see the same machine load, and prints a Markdown table of medians and of the
ratio record / plain for wall time, learning time, message and merge throughput, and CPU time
(user + sys of qfleet and every process it started and waited for), with a 95 % bootstrap
interval of that ratio: a ratio whose interval holds 1.0 is within the noise of this many runs.
`--control` records in neither arm (an A/A run): how far apart two identical arms come out.

    docs/bench/record-overhead.py [--bin target/release] [--reps 10] [--control] [-- RUN OPTIONS...]

Default run options: --robots 4 --map builtin:paper-30 --episodes 1000.
Only the standard library; the binaries must be built (`cargo build --release --bins`).
"""
import argparse
import json
import os
import random
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
    ap.add_argument("--control", action="store_true", help="A/A: the second arm does not record either")
    ap.add_argument("opts", nargs="*", help="qfleet run options (after --)")
    a = ap.parse_args()
    if a.reps < 1:
        sys.exit("--reps must be >= 1")
    opts = a.opts or ["--robots", "4", "--map", "builtin:paper-30", "--episodes", "1000"]
    runs = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="qfleet-recbench-") as tmp:
        for i in range(a.reps):
            for record in (False, True) if i % 2 == 0 else (True, False):
                runs[record].append(one(a.bin, opts, record and not a.control, tmp, 2 * i + record))
    keys = [
        ("wall_s", "wall time, s"),
        ("active_s", "learning time (first to last robot message), s"),
        ("messages_per_s", "messages/s"),
        ("q_merged_per_s", "Q-updates merged/s"),
        ("cpu_s", "CPU time, all processes, s"),
    ]
    arm = "plain (A/A control)" if a.control else "--record"
    print(f"`qfleet run {' '.join(opts)}`, {a.reps} runs each way, alternating; medians (min–max)\n")
    print(f"| figure | plain | {arm} | ratio | 95 % interval |")
    print("|---|---:|---:|---:|---:|")
    for k, name in keys:
        p = [r[k] for r in runs[False]]
        q = [r[k] for r in runs[True]]
        mp, mq = statistics.median(p), statistics.median(q)
        ratio = mq / mp if mp else float("nan")
        lo, hi = bootstrap(p, q)
        print(f"| {name} | {mp:.3g} ({min(p):.3g}–{max(p):.3g}) | {mq:.3g} ({min(q):.3g}–{max(q):.3g}) | {ratio:.3f} | {lo:.3f}–{hi:.3f} |")
    if not a.control:
        size = statistics.median(r["mcap_bytes"] for r in runs[True])
        print(f"\nrecording size: median {size / 1e6:.2f} MB per run")


def bootstrap(p, q, n=2000, seed=1):
    """95 % percentile interval of median(q) / median(p), both arms resampled with replacement."""
    rng = random.Random(seed)
    ratios = []
    for _ in range(n):
        mp = statistics.median(rng.choices(p, k=len(p)))
        mq = statistics.median(rng.choices(q, k=len(q)))
        if mp:
            ratios.append(mq / mp)
    ratios.sort()
    if not ratios:
        return float("nan"), float("nan")
    return ratios[int(0.025 * len(ratios))], ratios[int(0.975 * len(ratios)) - 1]


if __name__ == "__main__":
    main()
