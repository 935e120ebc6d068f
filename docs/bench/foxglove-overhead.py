#!/usr/bin/env python3
"""Foxglove server overhead: does a client that never reads slow a run down?

Runs `qfleet run` REPS times in each of three arms, interleaved (plain, reader, stalled, plain,
...) so that all see the same machine load, and prints a Markdown table of the robots'
environment steps per second (sum of every robot's env_steps over the run's learning time),
the learning time, messages/s and CPU time, as medians (min-max), with the ratio to the plain
arm and its 95 % bootstrap interval:

- plain:   no --foxglove
- reader:  --foxglove, one client subscribed to every channel that reads everything
- stalled: --foxglove, the same reading client plus a second one subscribed to every channel
           that never reads a byte (the server must drop its messages, never wait for it)

    docs/bench/foxglove-overhead.py [--bin target/debug] [--reps 10] [-- RUN OPTIONS...]

Default run options: --robots 4 --map builtin:paper-30 --episodes 3000. Only the standard
library (the clients speak foxglove.websocket.v1 over raw sockets).
"""
import argparse
import base64
import json
import os
import random
import resource
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time


def handshake(port, deadline):
    while True:
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            break
        except OSError:
            if time.monotonic() > deadline:
                return None
            time.sleep(0.01)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
               f"Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += s.recv(1)
    if b" 101 " not in head.split(b"\r\n")[0]:
        return None
    return s


def send_text(s, text):
    data = text.encode()
    mask = os.urandom(4)
    hdr = bytes([0x81])
    if len(data) < 126:
        hdr += bytes([0x80 | len(data)])
    else:
        hdr += bytes([0x80 | 126]) + struct.pack(">H", len(data))
    s.sendall(hdr + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


def recv_exact(s, n):
    b = b""
    while len(b) < n:
        chunk = s.recv(n - len(b))
        if not chunk:
            raise OSError("closed")
        b += chunk
    return b


def recv_frame(s):
    """One server frame (unmasked): (opcode, payload)."""
    h = recv_exact(s, 2)
    n = h[1] & 0x7F
    if n == 126:
        n = struct.unpack(">H", recv_exact(s, 2))[0]
    elif n == 127:
        n = struct.unpack(">Q", recv_exact(s, 8))[0]
    return h[0] & 0x0F, recv_exact(s, n)


def client(port, read, deadline, stats):
    """Connects, reads until the channels are advertised (scene and raw, in one message), subscribes
    to all of them, then reads everything (read=True) or never reads again (read=False)."""
    s = handshake(port, deadline)
    if s is None:
        return
    ids = []
    s.settimeout(10)
    try:
        while not ids:
            op, payload = recv_frame(s)
            if op == 1:
                m = json.loads(payload)
                if m.get("op") == "advertise":
                    ids += [c["id"] for c in m["channels"]]
    except (OSError, ValueError):
        return
    send_text(s, json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": c} for i, c in enumerate(ids, 1)]}))
    stats["connected"] = True
    if not read:
        stats["sock"] = s  # kept open, never read, closed by the caller
        return
    s.settimeout(1)
    n = 0
    while True:
        try:
            b = s.recv(1 << 16)
        except socket.timeout:
            continue
        except OSError:
            break
        if not b:
            break
        n += len(b)
    stats["bytes"] = n


def one(bin_dir, opts, arm, i):
    port = None
    cmd = [os.path.join(bin_dir, "qfleet"), "run", "--json", "--run-id", f"foxbench-{os.getpid()}-{i}"] + opts
    if arm != "plain":
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        cmd += ["--foxglove", f"127.0.0.1:{port}"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    threads, stats = [], [{}, {}]
    if arm != "plain":
        deadline = time.monotonic() + 10
        reader = threading.Thread(target=client, args=(port, True, deadline, stats[0]), daemon=True)
        reader.start()
        threads.append(reader)
        if arm == "stalled":
            client(port, False, deadline, stats[1])
    out, err = p.communicate()
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if stats[1].get("sock"):
        stats[1]["sock"].close()
    for t in threads:
        t.join(timeout=10)
    if p.returncode != 0:
        sys.exit(f"run failed ({p.returncode}): {' '.join(cmd)}\n{err}")
    r = json.loads(out)
    steps = sum(x["env_steps"] for x in r["robots"])
    active = r["throughput"]["active_s"]
    dropped = 0
    for line in err.splitlines():
        if "foxglove:" in line and "dropped for slow clients" in line:
            dropped = int(line.split(",")[2].split()[0])
    return {
        "steps_per_s": steps / active if active > 0 else 0.0,
        "active_s": active,
        "messages_per_s": r["throughput"]["messages_per_s"],
        "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
        "wall_s": wall,
        "connected": all(s.get("connected") for s in stats[: {"plain": 0, "reader": 1, "stalled": 2}[arm]]),
        "dropped_slow": dropped,
    }


def interval(a, b, n=2000):
    rng = random.Random(1)
    ratios = []
    for _ in range(n):
        ra = [rng.choice(a) for _ in a]
        rb = [rng.choice(b) for _ in b]
        ratios.append(statistics.median(rb) / statistics.median(ra))
    ratios.sort()
    return ratios[int(0.025 * n)], ratios[int(0.975 * n)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default="target/debug", help="directory of the qfleet binaries")
    ap.add_argument("--reps", type=int, default=10, help="runs per arm")
    ap.add_argument("opts", nargs="*", help="run options")
    args = ap.parse_args()
    opts = args.opts or ["--robots", "4", "--map", "builtin:paper-30", "--episodes", "3000"]
    arms = ["plain", "reader", "stalled"]
    res = {a: [] for a in arms}
    for i in range(args.reps):
        for j, a in enumerate(arms):
            res[a].append(one(args.bin, opts, a, i * 3 + j))
    print(f"`qfleet run {' '.join(opts)}`, {args.reps} runs per arm, interleaved; medians (min-max)\n")
    print("| figure | plain | reader | reader + stalled | reader / plain | stalled / plain (95 % interval) |")
    print("|---|---:|---:|---:|---:|---:|")
    for k, name in [("steps_per_s", "robots' env steps/s"), ("active_s", "learning time, s"),
                    ("messages_per_s", "messages/s"), ("cpu_s", "CPU time, all processes, s"),
                    ("wall_s", "wall time, s")]:
        cols = []
        for a in arms:
            v = [r[k] for r in res[a]]
            cols.append(f"{statistics.median(v):.4g} ({min(v):.3g}-{max(v):.3g})")
        base = [r[k] for r in res["plain"]]
        rd = [r[k] for r in res["reader"]]
        st = [r[k] for r in res["stalled"]]
        lo, hi = interval(base, st)
        print(f"| {name} | {' | '.join(cols)} | {statistics.median(rd) / statistics.median(base):.3f} | "
              f"{statistics.median(st) / statistics.median(base):.3f} ({lo:.3f}-{hi:.3f}) |")
    conn = sum(r["connected"] for r in res["stalled"])
    drops = [r["dropped_slow"] for r in res["stalled"]]
    print(f"\nstalled arm: both clients connected in {conn} of {args.reps} runs; "
          f"messages dropped for the stalled client: median {statistics.median(drops):.0f} (min {min(drops)}, max {max(drops)})")


if __name__ == "__main__":
    main()
