#!/usr/bin/env python3
"""One arm trained under different training settings, compared: learning curves, test results
and ADP against ADP paired over the test worlds.

    python3 scripts/compare_training.py --arm dwa-decremental-1.5-fit \
        docs/paper docs/experiments/learner-batch512 docs/experiments/learner-upi025

Each positional argument is the output directory of an `adp experiment` (its `stages.json`
names the store's results) that trained and evaluated `--arm` under its own `[train]`
settings; the first is the reference. Every directory must evaluate on the same test worlds
with the same runs, trim and run seed (the script checks), so the worlds pair.

Prints, as Markdown:
- per setting: `[td3] batch_size` and `updates_per_insert`, the learner's updates, the
  training's wall time and CPU time, ADP's test success and score per seed and their mean;
- the greedy learning curves on the `val` worlds (what `[train.greedy]` records during
  training), mean over seeds every 20,000 agent steps;
- per setting against the reference: ADP - ADP(reference) success and score, mean over seeds
  and worlds, with a two-level 95 % percentile-bootstrap interval (10,000 seeded resamples:
  each draws every setting's seeds with replacement, independently, and the worlds with
  replacement, jointly, so it counts how training seeds differ as well as worlds).

Per-world values are reduced as the experiment's report reduces them
(`EvalRecord::per_world_values`): per world, the runs sorted by charged time (a failed run
counts 50 s), `trim` dropped from each end, success rate and mean score over the rest.
"""

import argparse
import json
import os
import random
import re
import sys

FAILED_RUN_TIME = 50.0


def fail(msg):
    sys.exit(f"compare_training: {msg}")


def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError) as e:
        fail(f"cannot read {path}: {e}")


def td3_setting(config_toml):
    """`batch_size` and `updates_per_insert` of a run's `[td3]` table."""
    out = {}
    table = None
    with open(config_toml) as f:
        for line in f:
            line = line.split("#", 1)[0].strip()
            m = re.match(r"^\[(.*)\]$", line)
            if m:
                table = m.group(1)
            elif table == "td3" and "=" in line:
                k, v = (x.strip() for x in line.split("=", 1))
                if k in ("batch_size", "updates_per_insert"):
                    out[k] = float(v)
    return out


def per_world_values(record):
    """World id -> (success in [0, 1], mean score) after trimming, in record order."""
    trim = record["trim"]
    out = {}
    for w in record["per_world"]:
        runs = sorted(
            w["runs"],
            key=lambda r: r["time_s"] if r["status"] == "succeeded" else FAILED_RUN_TIME,
        )
        kept = runs[trim : len(runs) - trim]
        if not kept:
            fail(f"world {w['world']}: trim {trim} leaves no run")
        out[w["world"]] = (
            sum(r["status"] == "succeeded" for r in kept) / len(kept),
            sum(r["score"] for r in kept) / len(kept),
        )
    return out


def setting_of(out_dir, arm):
    """The trainings and ADP evaluations of `arm` in the experiment written to `out_dir`."""
    stages = load(os.path.join(out_dir, "stages.json"))
    trains, evals, ddp = {}, {}, []
    for s in stages:
        m = re.fullmatch(rf"train {re.escape(arm)} seed (\d+)", s["stage"])
        if m:
            trains[int(m.group(1))] = s["result"]
        m = re.fullmatch(rf"evaluate {re.escape(arm)} seed (\d+)", s["stage"])
        if m:
            evals[int(m.group(1))] = s["result"]
        if s["stage"].startswith("evaluate DDP ("):
            ddp.append(s["result"])
    seeds = sorted(set(trains) & set(evals))
    missing = sorted(set(trains) ^ set(evals))
    if missing:
        fail(f"{out_dir}: seeds {missing} of {arm} lack a training or an evaluation")
    if not seeds:
        fail(f"{out_dir}: no seed of {arm} trained and evaluated (is the arm's name right?)")
    runs = []
    for k in seeds:
        train_dir, record = trains[k], load(evals[k])
        if not os.path.exists(os.path.join(train_dir, "trained.json")):
            fail(f"{train_dir}: the training has not finished")
        status = load(os.path.join(train_dir, "status.json"))
        stage = load(os.path.join(train_dir, "stage.json"))
        curve = []
        with open(os.path.join(train_dir, "greedy_eval.jsonl")) as f:
            for line in f:
                if line.strip():
                    p = json.loads(line)
                    curve.append((p["agent_steps"], p["success"], p["score"]))
        runs.append(
            {
                "seed": k,
                "updates": status["updates"],
                "seconds": stage.get("seconds"),
                "cpu_s": stage.get("cpu_s"),
                "curve": curve,
                "record": record,
                "worlds": per_world_values(record),
            }
        )
    first = runs[0]["record"]
    ddp = [r for r in map(load, ddp) if (r["planner"], r["speed"]) == (first["planner"], first["speed"])]
    return {
        "dir": out_dir,
        "ddp": ddp[0] if ddp else None,
        "td3": td3_setting(os.path.join(trains[seeds[0]], "config.toml")),
        "runs": runs,
    }


def protocol(record):
    return (record["runs"], record["trim"], record["seed"], [w["world"] for w in record["per_world"]])


def two_level(ref, other, pick, resamples, seed):
    """Mean of other - ref over seeds and worlds, with its two-level bootstrap interval."""
    worlds = sorted(ref[0])
    rng = random.Random(seed)
    a = [[r[w][pick] for w in worlds] for r in ref]
    b = [[r[w][pick] for w in worlds] for r in other]

    def diff(sa, sb, ws):
        ma = sum(sum(a[s][w] for s in sa) / len(sa) for w in ws)
        mb = sum(sum(b[s][w] for s in sb) / len(sb) for w in ws)
        return (mb - ma) / len(ws)

    n = len(worlds)
    point = diff(range(len(a)), range(len(b)), range(n))
    means = sorted(
        diff(
            [rng.randrange(len(a)) for _ in a],
            [rng.randrange(len(b)) for _ in b],
            [rng.randrange(n) for _ in range(n)],
        )
        for _ in range(resamples)
    )
    lo = means[int(resamples * 0.025)]
    hi = means[-(-resamples * 975 // 1000) - 1]
    return point, lo, hi


def mean_sd(x):
    m = sum(x) / len(x)
    sd = (sum((v - m) ** 2 for v in x) / (len(x) - 1)) ** 0.5 if len(x) > 1 else 0.0
    return m, sd


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dirs", nargs="+", help="experiment output directories; the first is the reference")
    ap.add_argument("--arm", required=True, help="the arm's id, e.g. dwa-decremental-1.5-fit")
    ap.add_argument("--resamples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--every", type=int, default=20_000, help="learning-curve spacing (agent steps)")
    args = ap.parse_args()
    settings = [setting_of(d, args.arm) for d in args.dirs]
    ref_protocol = protocol(settings[0]["runs"][0]["record"])
    for s in settings:
        for r in s["runs"]:
            if protocol(r["record"]) != ref_protocol:
                fail(f"{s['dir']} seed {r['seed']}: evaluated on other worlds, runs, trim or run seed than {settings[0]['dir']}")

    def name(s):
        t = s["td3"]
        return f"batch {t.get('batch_size', 128):.0f}, {t.get('updates_per_insert', 1.0):g} update/insert"

    print(f"### {args.arm}: test worlds ({len(ref_protocol[3])} worlds x {ref_protocol[0]} runs, trim {ref_protocol[1]})\n")
    print("| setting | seeds | updates (mean) | wall h (mean) | CPU h (mean) | success % per seed | mean | score per seed | mean |")
    print("|---|---:|---:|---:|---:|---|---:|---|---:|")
    for s in settings:
        runs = s["runs"]
        succ = [100 * sum(v[0] for v in r["worlds"].values()) / len(r["worlds"]) for r in runs]
        score = [sum(v[1] for v in r["worlds"].values()) / len(r["worlds"]) for r in runs]
        upd = mean_sd([r["updates"] for r in runs])[0]
        wall = [r["seconds"] for r in runs if r["seconds"]]
        cpu = [r["cpu_s"] for r in runs if r["cpu_s"]]
        fmt_h = lambda v: f"{sum(v) / len(v) / 3600:.2f}" if v else "–"
        ms, ss = mean_sd(succ)
        mc, sc = mean_sd(score)
        print(
            f"| {name(s)} | {len(runs)} | {upd:,.0f} | {fmt_h(wall)} | {fmt_h(cpu)} "
            f"| {' / '.join(f'{v:.1f}' for v in succ)} | {ms:.1f} ± {ss:.1f} "
            f"| {' / '.join(f'{v:.3f}' for v in score)} | {mc:.3f} ± {sc:.3f} |"
        )

    ddp = settings[0]["ddp"]
    if ddp:
        v = per_world_values(ddp).values()
        print(
            f"| DDP (the control) | | | | | | {100 * sum(x[0] for x in v) / len(v):.1f} "
            f"| | {sum(x[1] for x in v) / len(v):.3f} |"
        )

    print(f"\n### Greedy learning curves on `val` (mean over seeds: success % / score)\n")
    steps = sorted({p[0] for s in settings for r in s["runs"] for p in r["curve"]})
    marks = []
    for target in range(args.every, max(steps) + 1, args.every):
        marks.append(target)
    print("| agent steps | " + " | ".join(name(s) for s in settings) + " |")
    print("|---:|" + "---|" * len(settings))
    for target in marks:
        cells = []
        for s in settings:
            pts = []
            for r in s["runs"]:
                near = [p for p in r["curve"] if abs(p[0] - target) <= 100]
                if near:
                    pts.append(near[0])
            if len(pts) == len(s["runs"]):
                cells.append(f"{sum(p[1] for p in pts) / len(pts):.1f} / {sum(p[2] for p in pts) / len(pts):.3f}")
            else:
                cells.append("–")
        print(f"| {target:,} | " + " | ".join(cells) + " |")

    print(f"\n### Against {name(settings[0])}: paired over the test worlds\n")
    print("| setting | success points [95 %] | score [95 %] |")
    print("|---|---|---|")
    ref = [r["worlds"] for r in settings[0]["runs"]]
    for s in settings[1:]:
        other = [r["worlds"] for r in s["runs"]]
        cells = []
        for pick, scale, f in ((0, 100.0, "{:+.1f}"), (1, 1.0, "{:+.4f}")):
            p, lo, hi = two_level(ref, other, pick, args.resamples, args.seed)
            cells.append(f"{f.format(p * scale)} [{f.format(lo * scale)}, {f.format(hi * scale)}]")
        print(f"| {name(s)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
