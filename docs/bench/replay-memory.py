#!/usr/bin/env python3
"""Writes the recordings `qfleet replay`'s memory bound is measured on (BENCHMARKS.md "Replay
memory"): a finished recording of SIZE_MB of `robot/state` messages in 1 MiB uncompressed
chunks, as `qfleet run --record` writes them; the same file cut short (a killed recorder);
the same file damaged near its start (4 KiB of zeros); and a finished recording holding one
240 MB message.

    python3 docs/bench/replay-memory.py DIR [SIZE_MB]
    /usr/bin/time -v target/release/qfleet replay DIR/good.mcap   # 'Maximum resident set size'
"""
import json
import struct
import sys
from pathlib import Path

MAGIC = b"\x89MCAP0\r\n"


def s(x: bytes) -> bytes:
    return struct.pack("<I", len(x)) + x


def rec(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def header() -> bytes:
    return rec(0x01, s(b"") + s(b"qfleet-bench"))


def schema() -> bytes:
    return rec(0x03, struct.pack("<H", 1) + s(b"qfleet.RobotState.v1") + s(b"jsonschema") + s(b"{}"))


def channel(topic: bytes) -> bytes:
    return rec(0x04, struct.pack("<HH", 1, 1) + s(topic) + s(b"json") + struct.pack("<I", 0))


def metadata(run: str) -> bytes:
    kv = s(b"run_id") + s(run.encode()) + s(b"map") + s(b"bench")
    return rec(0x0C, s(b"qfleet.run") + struct.pack("<I", len(kv)) + kv)


def message(seq: int, t: int, data: bytes) -> bytes:
    return rec(0x05, struct.pack("<HIQQ", 1, seq, t, t) + data)


def chunk(records: bytes, t0: int, t1: int) -> bytes:
    body = struct.pack("<QQQI", t0, t1, len(records), 0) + s(b"") + struct.pack("<Q", len(records)) + records
    return rec(0x06, body)


def tail() -> bytes:
    return rec(0x0F, struct.pack("<I", 0)) + rec(0x02, bytes(20)) + MAGIC


def main() -> None:
    out = Path(sys.argv[1])
    size_mb = int(sys.argv[2]) if len(sys.argv) > 2 else 1024
    out.mkdir(parents=True, exist_ok=True)
    run = "bench"
    topic = f"qfleet/{run}/robot/state".encode()
    start = MAGIC + header() + schema() + channel(topic) + metadata(run)
    t = 1_700_000_000_000_000_000
    good = out / "good.mcap"
    with open(good, "wb") as f:
        f.write(start)
        seq = 0
        written = len(start)
        while written < size_mb << 20:
            recs = bytearray()
            t0 = t
            while len(recs) < 1 << 20:
                m = {"robot_id": seq % 8, "goal_id": 0, "episode": seq // 1000, "step": seq,
                     "last_episode_steps": 57, "cell_x": seq % 30, "cell_y": seq % 29,
                     "status": 1, "seq": seq, "send_time_ns": t}
                recs += message(seq, t, json.dumps(m).encode())
                seq += 1
                t += 10_000
            c = chunk(bytes(recs), t0, t)
            f.write(c)
            written += len(c)
        f.write(tail())
    data = good.read_bytes()
    (out / "cut.mcap").write_bytes(data[: len(data) * 2 // 3])
    damaged = bytearray(data)
    damaged[len(start) + 100: len(start) + 100 + 4096] = bytes(4096)
    (out / "damaged.mcap").write_bytes(damaged)
    del data, damaged
    with open(out / "huge-message.mcap", "wb") as f:
        f.write(start)
        big = b'{"robot_id": 0, "pad": "' + b"x" * (240 << 20) + b'"}'
        f.write(chunk(message(0, t, big), t, t))
        f.write(tail())
    print(f"wrote {out}/good.mcap cut.mcap damaged.mcap huge-message.mcap ({seq} messages)")


if __name__ == "__main__":
    main()
