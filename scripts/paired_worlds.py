#!/usr/bin/env python3
"""Paired comparison of two rows of an `adp eval --out` JSON over worlds.

    python3 scripts/paired_worlds.py eval.json ddp:ddp+kf ddp+kf:ddp+padp-path [--planner dwa]
        [--worlds 320..340]

Each `A:B` names two rows by their fidelity label (the table's fidelity column); a label
may name another file's row as `label@other.json` (an evaluation of another build with the
same seed, worlds and runs). For every planner that has both rows (or only `--planner`),
each world's value is the mean over its runs (success as 0/1, in percent; the BARN score),
and the difference B - A is averaged over the worlds the two rows share (or those of
`--worlds`, a range `a..b` of ids). Rows of evaluations with the same seed run the same
seeds per world and run, so the worlds are paired. Prints, per planner and pair: the worlds, both means, the mean
difference with a 95 % Student t interval over worlds and a 95 % percentile bootstrap
interval (10,000 resamples of the worlds, seeded: the output repeats), and the worlds where
B did better and worse.
"""

import argparse
import json
import math
import random


def t_quantile(p, df):
    """The p-quantile of Student's t with `df` degrees of freedom (Simpson integration of the
    density, then bisection)."""

    def cdf(x):
        c = math.exp(math.lgamma((df + 1) / 2) - math.lgamma(df / 2)) / math.sqrt(df * math.pi)
        n = 2000
        h = x / n
        s = 0.0
        for i in range(n + 1):
            t = i * h
            w = 1 if i in (0, n) else (4 if i % 2 else 2)
            s += w * (1 + t * t / df) ** (-(df + 1) / 2)
        return 0.5 + c * s * h / 3

    lo, hi = 0.0, 50.0
    for _ in range(60):
        mid = (lo + hi) / 2
        if cdf(mid) < p:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


def per_world(row, metric):
    """World id -> the mean of `metric` over the world's runs."""
    out = {}
    for w in row["per_world"]:
        runs = w["runs"]
        if not runs:
            continue
        if metric == "success":
            vals = [100.0 if r["status"] == "succeeded" else 0.0 for r in runs]
        else:
            vals = [r["score"] for r in runs]
        out[w["world"]] = sum(vals) / len(vals)
    return out


def paired(a, b, rng):
    """Mean difference b - a over shared worlds, its t and bootstrap intervals."""
    worlds = sorted(set(a) & set(b))
    d = [b[w] - a[w] for w in worlds]
    n = len(d)
    mean = sum(d) / n
    if n > 1:
        sd = math.sqrt(sum((x - mean) ** 2 for x in d) / (n - 1))
        half = t_quantile(0.975, n - 1) * sd / math.sqrt(n)
    else:
        half = float("nan")
    boots = sorted(sum(rng.choice(d) for _ in range(n)) / n for _ in range(10_000))
    return {
        "worlds": n,
        "a": sum(a[w] for w in worlds) / n,
        "b": sum(b[w] for w in worlds) / n,
        "diff": mean,
        "t": (mean - half, mean + half),
        "boot": (boots[249], boots[9749]),
        "better": sum(x > 0 for x in d),
        "worse": sum(x < 0 for x in d),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("json")
    ap.add_argument("pairs", nargs="+", help="A:B fidelity labels, e.g. ddp:ddp+kf")
    ap.add_argument("--planner", help="only this planner (default: every planner with both rows)")
    ap.add_argument("--worlds", help="only the worlds of this range a..b (b excluded)")
    args = ap.parse_args()
    keep = None
    if args.worlds:
        lo, hi = (int(x) for x in args.worlds.split(".."))
        keep = set(range(lo, hi))
    files = {}

    def rows_of(path):
        if path not in files:
            rows = json.load(open(path))
            files[path] = rows["rows"] if isinstance(rows, dict) else rows
        return files[path]

    def find(planner, spec):
        label, _, path = spec.partition("@")
        return [r for r in rows_of(path or args.json) if r["planner"] == planner and r["fidelity_label"] == label]

    def values(row, metric):
        v = per_world(row, metric)
        return {w: x for w, x in v.items() if keep is None or w in keep}

    print("| planner | A | B | metric | worlds | A | B | B - A | 95 % t interval | 95 % bootstrap | B better / worse |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for spec in args.pairs:
        if spec.count(":") != 1:
            raise SystemExit(f"pair `{spec}`: expected A:B, two fidelity labels")
        la, lb = spec.split(":")
        planners = sorted({r["planner"] for r in rows_of(args.json)})
        for planner in planners:
            if args.planner and planner != args.planner:
                continue
            ra, rb = find(planner, la), find(planner, lb)
            if not ra or not rb:
                continue
            if len(ra) > 1 or len(rb) > 1:
                raise SystemExit(f"{planner}: more than one row labelled {la} or {lb} (speeds or lidars?)")
            for metric in ("success", "score"):
                rng = random.Random(0)
                p = paired(values(ra[0], metric), values(rb[0], metric), rng)
                f = "{:.1f}" if metric == "success" else "{:.3f}"
                iv = lambda x: "[" + ", ".join(f.format(v) for v in x) + "]"
                print(
                    f"| {planner} | {la} | {lb} | {metric}{' (%)' if metric == 'success' else ''} | {p['worlds']} "
                    f"| {f.format(p['a'])} | {f.format(p['b'])} | {f.format(p['diff'])} | {iv(p['t'])} "
                    f"| {iv(p['boot'])} | {p['better']} / {p['worse']} |"
                )


if __name__ == "__main__":
    main()
