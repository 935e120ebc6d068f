#!/usr/bin/env python3
"""Writes a MovingAI .scen of N random start/goal pairs on a .map: distinct starts, distinct
goals, no goal on its own start, each goal reachable from its start (4-connected), deterministic for a seed.

    python3 docs/bench/random-scen.py MAP N SEED > FILE.scen
"""
import random
import sys
from collections import deque


def load(path):
    lines = open(path).read().splitlines()
    h = int(next(l for l in lines if l.startswith("height")).split()[1])
    w = int(next(l for l in lines if l.startswith("width")).split()[1])
    rows = lines[lines.index("map") + 1:][:h]
    free = {(x, y) for y, r in enumerate(rows) for x, c in enumerate(r[:w]) if c in ".GS"}
    return w, h, free


def component(free, s):
    seen, q = {s}, deque([s])
    while q:
        x, y = q.popleft()
        for n in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
            if n in free and n not in seen:
                seen.add(n)
                q.append(n)
    return seen


def main():
    path, n, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    w, h, free = load(path)
    rnd = random.Random(seed)
    cells = sorted(free)
    # the largest connected part: every pair in it is solvable alone
    best = max((component(free, c) for c in rnd.sample(cells, min(8, len(cells)))), key=len)
    part = sorted(best)
    starts = rnd.sample(part, n)
    goals = rnd.sample(part, n)
    # a robot needs a path to learn: no goal on its own start
    while any(s == g for s, g in zip(starts, goals)):
        goals = rnd.sample(part, n)
    name = path.rsplit("/", 1)[-1]
    print("version 1")
    for (sx, sy), (gx, gy) in zip(starts, goals):
        print(f"0\t{name}\t{w}\t{h}\t{sx}\t{sy}\t{gx}\t{gy}\t0")


main()
