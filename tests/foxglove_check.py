#!/usr/bin/env python3
"""An outside check of qfleet's Foxglove output, sharing no code with it.

    foxglove_check.py live --port PORT --map MAP --robots N [--timeout S]
    foxglove_check.py mcap --file FILE.mcap --map MAP --robots N

`live` speaks foxglove.websocket.v1 to `qfleet run ... --foxglove 127.0.0.1:PORT` with the
`websockets` package: it expects serverInfo, advertisements of /map (foxglove.Grid) and
/robots (foxglove.SceneUpdate), subscribes to both, decodes the binary message frames
(opcode 1, subscription id u32 LE, timestamp u64 LE, JSON), and checks that the grid has the
map's size and cells and that every robot it sees stands on a free cell. `mcap` reads a
`--record` file with the `mcap` package and checks the same from its channels. Both print one
JSON summary line and exit 0, or print why and exit 1.

The map is the ASCII or MovingAI text of the map file (`#`/`@`/`T` walls). Coordinates as
qfleet documents them: cell (x, y), row y from the top of the file, is the unit square whose
centre is (x + 0.5, height - y - 0.5) in frame `map`; the grid's data row 0 is the bottom row.
"""
import argparse
import base64
import json
import math
import struct
import sys
import time

WALLS = set("#@TOW")


def read_map(path):
    lines = [l.rstrip("\n") for l in open(path, encoding="utf-8")]
    if lines and lines[0].startswith("type"):
        lines = lines[lines.index("map") + 1:]
    rows = [l for l in lines if l and not l.startswith(";")]
    width = len(rows[0])
    if any(len(r) != width for r in rows):
        fail(f"{path}: rows of different lengths")
    return rows


def fail(why):
    print(f"FAIL: {why}", file=sys.stderr)
    sys.exit(1)


def is_wall(rows, x, y):
    return rows[y][x] in WALLS


def check_grid(grid, rows):
    """The grid message against the map: size, and the `wall` field of every cell."""
    h, w = len(rows), len(rows[0])
    if grid["column_count"] != w:
        fail(f"grid has {grid['column_count']} columns, the map {w}")
    data = base64.b64decode(grid["data"])
    stride, cell = grid["row_stride"], grid["cell_stride"]
    if len(data) != stride * h:
        fail(f"grid data is {len(data)} bytes, {h} rows of {stride} expected")
    offset = {f["name"]: f["offset"] for f in grid["fields"]}["wall"]
    for row in range(h):
        y = h - 1 - row
        for x in range(w):
            wall = data[row * stride + x * cell + offset]
            if bool(wall) != is_wall(rows, x, y):
                fail(f"grid cell ({x}, {y}) says wall={wall}, the map says {rows[y][x]!r}")
    return {"width": w, "height": len(data) // stride}


def robot_cells(update, rows):
    """(robot id, x, y) of every robot entity of a SceneUpdate, each checked to be on a free cell."""
    h = len(rows)
    found = []
    for e in update["entities"]:
        if not e["id"].startswith("robot-"):
            continue
        if e["frame_id"] != "map":
            fail(f"{e['id']} in frame {e['frame_id']!r}")
        p = e["cubes"][0]["pose"]["position"]
        x, y = math.floor(p["x"]), h - 1 - math.floor(p["y"])
        if not (0 <= x < len(rows[0]) and 0 <= y < h):
            fail(f"{e['id']} at ({p['x']}, {p['y']}): off the map")
        if is_wall(rows, x, y):
            fail(f"{e['id']} at cell ({x}, {y}), a wall")
        found.append((int(e["id"][len("robot-"):]), x, y))
    return found


def live(args, rows):
    from websockets.sync.client import connect

    deadline = time.monotonic() + args.timeout
    ws = None
    while ws is None:
        try:
            ws = connect(f"ws://127.0.0.1:{args.port}", subprotocols=["foxglove.websocket.v1"],
                         open_timeout=10, max_size=None)
        except OSError:
            if time.monotonic() > deadline:
                fail("could not connect")
            time.sleep(0.2)
    if ws.subprotocol != "foxglove.websocket.v1":
        fail(f"subprotocol {ws.subprotocol!r}")
    info = json.loads(ws.recv(timeout=10))
    if info.get("op") != "serverInfo":
        fail(f"first message is not serverInfo: {info}")
    channels = {}
    while not {"/map", "/robots"} <= channels.keys():
        m = ws.recv(timeout=max(1, deadline - time.monotonic()))
        if isinstance(m, str):
            v = json.loads(m)
            if v.get("op") == "advertise":
                for c in v["channels"]:
                    channels[c["topic"]] = c
    for topic, schema in (("/map", "foxglove.Grid"), ("/robots", "foxglove.SceneUpdate")):
        c = channels[topic]
        if c["schemaName"] != schema or c["encoding"] != "json":
            fail(f"{topic} advertised as {c['schemaName']} / {c['encoding']}")
        json.loads(c["schema"])
    subs = {1: "/map", 2: "/robots"}
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": channels[t]["id"]} for i, t in subs.items()]}))
    grid = None
    updates = {}
    cells = {}
    while time.monotonic() < deadline:
        try:
            m = ws.recv(timeout=1)
        except TimeoutError:
            continue
        except Exception:
            break  # the run ended and closed the connection
        if isinstance(m, str):
            continue
        op, sub, ts = struct.unpack_from("<BIQ", m)
        if op != 1:
            fail(f"binary opcode {op}")
        msg = json.loads(m[13:])
        if subs.get(sub) == "/map":
            grid = check_grid(msg, rows)
        elif subs.get(sub) == "/robots":
            for rid, x, y in robot_cells(msg, rows):
                updates[rid] = updates.get(rid, 0) + 1
                cells.setdefault(rid, set()).add((x, y))
        if grid and len(updates) >= args.robots and min(updates.values()) >= 3:
            break
    ws.close()
    if grid is None:
        fail("no grid received")
    if len(updates) < args.robots:
        fail(f"saw robots {sorted(updates)}, expected {args.robots}")
    return {"grid": grid, "robot_updates": updates, "distinct_cells": {k: len(v) for k, v in cells.items()},
            "channels": len(channels)}


def from_mcap(args, rows):
    from mcap.reader import make_reader

    schemas, grids, robots, counts = {}, [], {}, {}
    with open(args.file, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.message_encoding != "json":
                fail(f"{channel.topic} in {channel.message_encoding}")
            msg = json.loads(message.data)
            if channel.topic == "/map":
                grids.append(check_grid(msg, rows))
            elif channel.topic == "/robots":
                for rid, x, y in robot_cells(msg, rows):
                    robots[rid] = robots.get(rid, 0) + 1
    want = {"/map": "foxglove.Grid", "/robots": "foxglove.SceneUpdate", "/paths": "foxglove.SceneUpdate",
            "/markers": "foxglove.SceneUpdate", "/tf": "foxglove.FrameTransform"}
    for topic, name in want.items():
        if topic not in schemas:
            fail(f"no {topic} channel with messages; channels: {sorted(schemas)}")
        if schemas[topic][:2] != (name, "jsonschema"):
            fail(f"{topic} has schema {schemas[topic]}")
    if len(grids) != 1:
        fail(f"{len(grids)} grid messages, one expected")
    if len(robots) != args.robots:
        fail(f"robots {sorted(robots)} in /robots, {args.robots} expected")
    return {"grid": grids[0], "robot_updates": robots, "counts": counts}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["live", "mcap"])
    ap.add_argument("--port", type=int)
    ap.add_argument("--file")
    ap.add_argument("--map", required=True)
    ap.add_argument("--robots", type=int, required=True)
    ap.add_argument("--timeout", type=float, default=60)
    args = ap.parse_args()
    rows = read_map(args.map)
    out = live(args, rows) if args.mode == "live" else from_mcap(args, rows)
    print(json.dumps(out, default=str))


if __name__ == "__main__":
    main()
