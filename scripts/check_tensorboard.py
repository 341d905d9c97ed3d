#!/usr/bin/env python3
"""Read a TensorBoard run written by adp with the `tensorboard` package's own reader.

Usage: check_tensorboard.py DIR

DIR holds expected.json ({"run": name, "scalars": {tag: [[step, value], ...]}}) and the run
directory it names; `cargo test` writes one to target/tmp/tensorboard-check. Loads the run with
tensorboard's EventAccumulator (which verifies the record CRCs and applies the purge of a
resumed run) and checks that every expected curve is there with exactly these steps and values,
and no other scalar tags. Exits 0 when they match, 1 with a message otherwise.
"""

import json
import math
import sys

from tensorboard.backend.event_processing import event_accumulator

import check_main


def check(directory):
    """A list of failure messages (empty when the curves match)."""
    expected = json.loads((directory / "expected.json").read_text())
    accumulator = event_accumulator.EventAccumulator(
        str(directory / expected["run"]), size_guidance={event_accumulator.SCALARS: 0}
    )
    accumulator.Reload()
    tags = sorted(accumulator.Tags()["scalars"])
    failures = []
    if tags != sorted(expected["scalars"]):
        failures.append(f"scalar tags {tags}, expected {sorted(expected['scalars'])}")
    for tag, points in expected["scalars"].items():
        if tag not in tags:
            continue
        got = [(e.step, e.value) for e in accumulator.Scalars(tag)]
        if [s for s, _ in got] != [s for s, _ in points]:
            failures.append(f"{tag}: steps {[s for s, _ in got]}, expected {[s for s, _ in points]}")
        elif not all(math.isclose(g, w, rel_tol=1e-6, abs_tol=1e-6) for (_, g), (_, w) in zip(got, points)):
            failures.append(f"{tag}: values {got}, expected {points}")
        else:
            print(f"{tag}: {len(got)} points, steps {got[0][0]}..{got[-1][0]}, values match")
    return failures


def main(argv):
    return check_main.run("check_tensorboard", __doc__, check, argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
