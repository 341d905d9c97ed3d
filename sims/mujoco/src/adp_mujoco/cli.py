"""`adp-mujoco` (also `python -m adp_mujoco`): evaluate the project's planners in MuJoCo.

    adp-mujoco eval --planner dwa --fidelity ddp --max-speed 1.5 --worlds 0..5 --out rows.json

runs every (planner, fidelity, speed) row on every world, `--runs` runs a world (each with
its own seed and, with `--jitter-m`/`--jitter-yaw`, its own start), trims the `--trim` fastest
and slowest runs of each world, prints the table and writes the rows as JSON in `adp eval
--out`'s format (eval/src/evaluate.rs, `Row`), with `"simulator": "mujoco"` added. A run the
simulator could not finish (a SimError) is kept in `per_world` with status "error" and
counted as a failure."""

import argparse
import json
import random
import sys
import time
from typing import Any, Dict, List

from .episode import PLANNERS, decremental_schedule, navigator, run_episode
from .jackal import BASES, JackalParams, base_params
from .world import load_world
from .errors import SimError

FAILED_RUN_TIME = 50.0
"""Time charged to a failed run in `avg_time_s` (eval/src/evaluate.rs FAILED_RUN_TIME)."""

MASK = (1 << 64) - 1


def run_seed(base: int, world: int, run: int) -> int:
    """The project's seed of one run (eval/src/evaluate.rs `run_seed`, SplitMix64)."""
    z = (base ^ ((world * 0x9E3779B97F4A7C15) & MASK) ^ ((run * 0xD1B54A32D192ED03) & MASK)) & MASK
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def charged_time(r: Dict[str, Any]) -> float:
    return r["time_s"] if r["status"] == "succeeded" else FAILED_RUN_TIME


def summarize(per_world: List[Dict[str, Any]], trim: int):
    """Per world: sort by charged time, drop `trim` best and worst, average over the rest
    (eval/src/evaluate.rs `summarize`)."""
    kept = []
    for w in per_world:
        runs = sorted(w["runs"], key=charged_time)
        kept.extend(runs[trim:len(runs) - trim])
    n = max(len(kept), 1)
    pct = lambda s: 100.0 * sum(r["status"] == s for r in kept) / n  # noqa: E731
    return {
        "success_pct": pct("succeeded"),
        "avg_time_s": sum(charged_time(r) for r in kept) / n,
        "avg_score": sum(r["score"] for r in kept) / n,
        "collision_pct": pct("collided"),
        "timeout_pct": pct("timed_out"),
        "error_pct": pct("error"),
        "episodes": len(kept),
    }


def jittered(world: Dict[str, Any], seed: int, jitter_m: float, jitter_yaw: float) -> Dict[str, Any]:
    if jitter_m == 0 and jitter_yaw == 0:
        return world
    rng = random.Random(seed)
    x, y, yaw = world["start"]
    w = dict(world)
    w["start"] = (x + rng.uniform(-jitter_m, jitter_m), y + rng.uniform(-jitter_m, jitter_m),
                  yaw + rng.uniform(-jitter_yaw, jitter_yaw))
    return w


def evaluate(args) -> List[Dict[str, Any]]:
    import adp_runtime

    ids = adp_runtime.select_worlds(args.worlds)
    constant, label = None, {}
    if "constant" in args.fidelity:
        p, horizon, steps, alpha = parse_constant(args.constant)
        dts_checks = decremental_schedule(p, horizon, steps, alpha)
        constant = lambda sim, k: dts_checks  # noqa: E731
        label["constant"] = f"constant p={p:g} T={horizon:g} N={steps} alpha={alpha:g}"
    worlds = {i: load_world(i) for i in ids}
    params = _params(args)
    rows = []
    for planner in args.planner:
        for fidelity in args.fidelity:
            for speed in args.max_speed:
                per_world, cycles, work, modelled, late, plan_s = [], 0, [0] * 5, 0.0, 0, 0.0
                t0 = time.perf_counter()
                for wid in ids:
                    runs = []
                    for k in range(args.runs):
                        seed = run_seed(args.seed, wid, k)
                        fixed = "ddp" if fidelity == "constant" else fidelity
                        nav = navigator(planner, speed, fixed=fixed, seed=seed & 0xFFFF_FFFF,
                                        policy=args.policy)
                        tally = _Tally(nav)
                        world = jittered(worlds[wid], seed, args.jitter_m, args.jitter_yaw)
                        r = run_episode(world, tally, seed=seed & 0xFFFF_FFFF, params=params,
                                        schedule=constant if fidelity == "constant" else None)
                        r["world"] = wid
                        cycles += tally.cycles
                        work = [a + b for a, b in zip(work, tally.work)]
                        modelled += tally.modelled
                        late += tally.late
                        plan_s += tally.plan_s
                        runs.append({k2: r[k2] for k2 in ("world", "status", "time_s", "sim_time_s", "score", "distance_m")}
                                    | ({"error": r["error"]} if r["error"] else {}))
                        if not args.quiet:
                            print(f"{planner} {fidelity} {speed} world {wid} run {k}: {r['status']} "
                                  f"{r['time_s']:.2f} s score {r['score']:.3f} "
                                  f"({r['physics_steps_per_s']:.0f} physics steps/s)", file=sys.stderr)
                    per_world.append({"world": wid, "runs": runs})
                n = max(cycles, 1)
                row = {"simulator": "mujoco", "planner": planner, "fidelity": fidelity,
                       "fidelity_label": label.get(fidelity, fidelity), "prediction": "off", "max_speed": speed,
                       "base": {"name": args.base, "track_multiplier": params.track_multiplier,
                                "yaw_kp": params.yaw_kp, "yaw_ki": params.yaw_ki, "yaw_i_max": params.yaw_i_max,
                                "yaw_slip": list(params.yaw_slip)}}
                row.update(summarize(per_world, args.trim))
                row.update({
                    "check_points_per_cycle": work[4] / n,
                    "plan_ms_per_cycle": 1000.0 * plan_s / n,
                    "compute_model": "runtime" if modelled else "free",
                    "units_per_cycle": dict(zip(("cells", "samples", "draws", "steps", "points"), (u / n for u in work))),
                    "modelled_ms_per_cycle": 1000.0 * modelled / n,
                    "late_cycles_pct": 100.0 * late / n,
                    "wall_s": time.perf_counter() - t0,
                    "per_world": per_world,
                })
                rows.append(row)
    return rows


def parse_constant(text):
    """`--constant P,T,N,ALPHA`: a decremental schedule's parameters, each in the ADP action
    space's range (p 1.0..1.7, T 1.6..2.2 s, N 15..22, alpha 0..0.6)."""
    if not text:
        raise ValueError("--fidelity constant needs --constant P,T,N,ALPHA (e.g. 1.7,2.0,20,0 for DDP)")
    try:
        p, horizon, steps, alpha = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--constant {text}: expected four numbers P,T,N,ALPHA") from None
    ok = 1.0 <= p <= 1.7 and 1.6 <= horizon <= 2.2 and 15 <= steps <= 22 and 0.0 <= alpha <= 0.6
    if not ok:
        raise ValueError(f"--constant {text}: outside the decremental space (p 1.0..1.7, T 1.6..2.2, "
                         "N 15..22, alpha 0..0.6)")
    return p, horizon, int(round(steps)), alpha


class _Tally:
    """A navigator wrapper that counts what its planning cycles did."""

    def __init__(self, nav):
        self.nav, self.cycles, self.work, self.modelled, self.late, self.plan_s = nav, 0, [0] * 5, 0.0, 0, 0.0

    @property
    def episode(self):
        return self.nav.episode

    def set_schedule(self, *args):
        self.nav.set_schedule(*args)

    def cycle(self, **kw):
        t = time.perf_counter()
        out = self.nav.cycle(**kw)
        self.plan_s += time.perf_counter() - t
        if out.planned:
            self.cycles += 1
            self.work = [a + b for a, b in zip(self.work, out.work)]
            if out.compute_s is not None:
                self.modelled += out.compute_s
                self.late += out.compute_s > self.nav.control_dt
        return out


def table(rows) -> str:
    head = "| planner | fidelity | max speed (m/s) | success (%) | avg time (s) | avg score | collision (%) | timeout (%) | error (%) | episodes |"
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(f"| {r['planner']} | {r['fidelity_label']} | {r['max_speed']} | {r['success_pct']:.2f} | "
                     f"{r['avg_time_s']:.2f} | {r['avg_score']:.3f} | {r['collision_pct']:.2f} | "
                     f"{r['timeout_pct']:.2f} | {r['error_pct']:.2f} | {r['episodes']} |")
    return "\n".join(lines) + "\n"


def _base_options(p) -> None:
    p.add_argument("--base", choices=BASES, default="calibrated",
                   help="the base controller: 'calibrated' (default: the Jackal controller plus a "
                   "gyro yaw-rate PI loop fitted so the robot turns at the commanded rate, "
                   "calibrated to the project's simulator's unicycle response, not to the real "
                   "robot), 'published' (Clearpath's controller, no yaw loop) or 'calibrated-slip' (the "
                   "loop tracking gazebo-jackal's slipped yaw rate: an experiment)")
    p.add_argument("--track-multiplier", type=float, default=None,
                   help="override the base's wheel_separation_multiplier (both bases: the "
                   "Jackal's 1.5)")


def _params(args) -> JackalParams:
    kw = {} if args.track_multiplier is None else {"track_multiplier": args.track_multiplier}
    return base_params(args.base, **kw)


def actor(args) -> int:
    """`adp-mujoco actor`: serves the learner until its run is over."""
    try:
        import adp_client

        from .training import MujocoEnvironment
    except ImportError as e:
        print(f"adp-mujoco actor: {e} (install clients/python)", file=sys.stderr)
        return 2
    env = MujocoEnvironment(_params(args))
    try:
        adp_client.Actor(args.learner, env, rank=args.rank, token_file=args.token_file, tls_ca=args.tls_ca,
                         tls_cert=args.tls_cert, tls_key=args.tls_key, tls_domain=args.tls_domain,
                         give_up_after=args.give_up_after).run()
    except adp_client.AdpError as e:
        print(f"adp-mujoco actor: {e}", file=sys.stderr)
        return 1
    print(f"adp-mujoco actor {args.rank}: {env.errors} episodes ended by a simulator error", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="adp-mujoco", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    ev = sub.add_parser("eval", help="run planners on worlds in MuJoCo; print the table, write JSON rows")
    ev.add_argument("--planner", nargs="+", default=["dwa"], choices=PLANNERS)
    ev.add_argument("--fidelity", nargs="+", default=["ddp"], choices=["ddp", "vanilla", "constant"],
                    help="the schedule: DDP's, vanilla, or the constant ADP action of --constant")
    ev.add_argument("--constant", help="P,T,N,ALPHA: the decremental schedule of --fidelity constant")
    ev.add_argument("--max-speed", nargs="+", type=float, default=[1.5])
    ev.add_argument("--worlds", default="3", help="a selection as adp eval --worlds reads it: test, 0..10, 3,7")
    ev.add_argument("--runs", type=int, default=1)
    ev.add_argument("--trim", type=int, default=0)
    ev.add_argument("--seed", type=int, default=0)
    ev.add_argument("--jitter-m", type=float, default=0.0, help="start moved by U(-j, j) in x and y (m)")
    ev.add_argument("--jitter-yaw", type=float, default=0.0, help="start heading moved by U(-j, j) (rad)")
    ev.add_argument("--policy", help="an adp export directory: the policy chooses the schedule")
    _base_options(ev)
    ev.add_argument("--out", help="write the rows as JSON here")
    ev.add_argument("--quiet", action="store_true")
    ac = sub.add_parser("actor", help="a MuJoCo actor of an `adp learner` run (needs adp_client)")
    ac.add_argument("--learner", required=True, help="the learner's address: host:port or unix:PATH")
    ac.add_argument("--token-file", help="the run's token file")
    ac.add_argument("--rank", type=int, default=0)
    ac.add_argument("--tls-ca")
    ac.add_argument("--tls-cert")
    ac.add_argument("--tls-key")
    ac.add_argument("--tls-domain")
    ac.add_argument("--give-up-after", type=float, default=60.0)
    _base_options(ac)
    ca = sub.add_parser("calibrate", help="step and turn responses of the published and calibrated "
                        "bases beside the project's gazebo-jackal profile; the figure with --out")
    ca.add_argument("--out", help="write the figure (PNG) here (needs matplotlib)")
    ca.add_argument("--commands", action="store_true",
                    help="also print which (v, w) DWA and MPPI command (DDP, every 15th test world)")
    args = ap.parse_args(argv)
    # MuJoCo's warnings to stderr, not to MUJOCO_LOG.TXT in the working directory (a
    # diverged state also ends its episode as a PhysicsError, recorded in its run).
    import mujoco

    mujoco.set_mju_user_warning(lambda msg: print(f"mujoco: {msg}", file=sys.stderr))
    if args.command == "actor":
        return actor(args)
    if args.command == "calibrate":
        from .calibrate import command_usage, run

        run(args.out)
        if args.commands:
            command_usage()
        return 0
    if args.runs < 1 or not (0 <= 2 * args.trim < args.runs):
        ap.error("--runs must be >= 1 and --trim less than half of --runs")
    try:
        rows = evaluate(args)
    except (SimError, ValueError) as e:
        print(f"adp-mujoco: {e}", file=sys.stderr)
        return 2
    print(table(rows), end="")
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            json.dump(rows, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
