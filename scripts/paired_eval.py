#!/usr/bin/env python3
"""Paired comparison of two rows of an `adp eval --out FILE` JSON over worlds.

    python3 scripts/paired_eval.py eval.json [--base 0] [--other 1] [--trim 2] [--resamples 10000]

Per world, each row's runs are trimmed as `adp eval` trims them (sorted by charged time, a
failure charged 50 s, `--trim` dropped from each end) and their scores and successes averaged;
the difference other - base is then averaged over the worlds and given a 95 % percentile
interval from a paired bootstrap over worlds (seeded, so the figure reproduces). The guide's
main-job measurement (docs/guide/getting-started.md) was made with it.
"""

import argparse
import json
import random

FAILURE_CHARGE_S = 50.0


def per_world(row, trim):
    """{world: (mean score, success rate)} of one row after trimming each world's runs."""
    out = {}
    for w in row["per_world"]:
        runs = w["runs"]
        charged = sorted(
            (r["time_s"] if r["status"] == "succeeded" else FAILURE_CHARGE_S, i) for i, r in enumerate(runs)
        )
        kept = [runs[i] for _, i in charged[trim : len(charged) - trim]]
        if not kept:
            raise SystemExit(f"world {w['world']}: {len(runs)} runs leave none after trimming {trim} from each end")
        out[w["world"]] = (
            sum(r["score"] for r in kept) / len(kept),
            sum(r["status"] == "succeeded" for r in kept) / len(kept),
        )
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("eval_json")
    ap.add_argument("--base", type=int, default=0, help="row index of the baseline (default 0)")
    ap.add_argument("--other", type=int, default=1, help="row index compared with it (default 1)")
    ap.add_argument("--trim", type=int, default=2)
    ap.add_argument("--resamples", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    with open(a.eval_json) as f:
        rows = json.load(f)
    base, other = per_world(rows[a.base], a.trim), per_world(rows[a.other], a.trim)
    if sorted(base) != sorted(other):
        raise SystemExit("the two rows were run on different worlds: no paired comparison")
    worlds = sorted(base)
    diff = [other[w][0] - base[w][0] for w in worlds]
    mean = sum(diff) / len(diff)
    rng = random.Random(a.seed)
    boots = sorted(sum(diff[rng.randrange(len(diff))] for _ in diff) / len(diff) for _ in range(a.resamples))
    lo, hi = boots[int(0.025 * a.resamples)], boots[int(0.975 * a.resamples) - 1]
    name = lambda r: f"{rows[r]['planner']} {rows[r]['fidelity_label']}"
    print(f"{len(worlds)} worlds, {a.trim} runs trimmed from each end")
    for r, pw in ((a.base, base), (a.other, other)):
        score = sum(v[0] for v in pw.values()) / len(pw)
        succ = 100 * sum(v[1] for v in pw.values()) / len(pw)
        print(f"  {name(r)}: success {succ:.2f} %, score {score:.4f}")
    print(f"{name(a.other)} - {name(a.base)} score {mean:+.4f} [{lo:+.4f}, {hi:+.4f}] (95 % paired bootstrap over worlds)")
    better = sum(d > 1e-12 for d in diff)
    worse = sum(d < -1e-12 for d in diff)
    print(f"worlds better / worse / equal: {better} / {worse} / {len(diff) - better - worse}")


if __name__ == "__main__":
    main()
