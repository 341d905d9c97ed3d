"""Drives a simulated BARN world with the ADP runtime from Python: each control period the
simulated robot's scan, odometry and goal go into the navigator and its command comes back.
On a robot the inputs come from its drivers and the command goes to its base.

    python runtime-py/examples/drive_world.py runtime/examples/runtime.toml [WORLD [SEED]]
"""

import sys

import adp_runtime


def main(argv):
    if len(argv) < 2:
        print(f"usage: {argv[0]} CONFIG [WORLD [SEED]]", file=sys.stderr)
        return 2
    world = int(argv[2]) if len(argv) > 2 else 0
    seed = int(argv[3]) if len(argv) > 3 else 0
    nav = adp_runtime.Navigator(argv[1])
    sim = adp_runtime.Sim(nav, world, seed)
    status, cycles, refused = "running", 0, 0
    while status == "running":
        try:
            status = sim.step(nav.cycle(**sim.observe()))
        except adp_runtime.RefusedInput as e:
            print(f"cycle {cycles} refused: {e.args[0]}", file=sys.stderr)
            refused += 1
            status = sim.drive(adp_runtime.STOP)
        cycles += 1
    status, time_s, score = sim.result()
    print(f"world {world}: {status.replace('_', ' ')} in {time_s:.2f} s, score {score:.3f}; {cycles} cycles, {refused} refused")
    return 0 if status == "succeeded" else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
