#!/usr/bin/env python3
"""Checks that two `adp eval --out` JSON files hold the same results, bit for bit.

    python3 scripts/same_results.py before.json after.json

Every field is compared exactly except the wall-clock ones (`plan_ms_per_cycle`): a
speed-up that claims "results unchanged" (issue 27) must pass this on the 75-world table.
Prints the first differing field and exits 1, or prints the number of episodes compared.
"""

import json
import sys

WALL_CLOCK = {"plan_ms_per_cycle"}


def walk(a, b, path):
    """Yields the path of every leaf where `a` and `b` differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in WALL_CLOCK:
                continue
            if k not in a or k not in b:
                yield f"{path}/{k} (only in {'after' if k in b else 'before'})"
            else:
                yield from walk(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{path} (length {len(a)} vs {len(b)})"
        for i, (x, y) in enumerate(zip(a, b)):
            yield from walk(x, y, f"{path}[{i}]")
    elif a != b:
        yield f"{path}: {a!r} vs {b!r}"


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    before, after = (json.load(open(p)) for p in sys.argv[1:])
    for diff in walk(before, after, ""):
        print(f"differs at {diff}")
        sys.exit(1)
    episodes = sum(row.get("episodes", 0) for row in before)
    print(f"same results: {len(before)} rows, {episodes} episodes")


if __name__ == "__main__":
    main()
