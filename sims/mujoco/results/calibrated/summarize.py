"""Summarizes the records of this folder (issue 73 item 5): per row the success, score,
hardest-50 success and end states; per pair of rows the worlds both solve, only one solves,
and an exact two-sided sign test on those discordant worlds (McNemar's exact test).

    python sims/mujoco/results/calibrated/summarize.py A.json B.json ...

prints every row, then every pair of rows with the same planner and speed. Needs
adp_runtime (for the hardest-50 ids, `select_worlds("hardest50")`)."""

import json
import math
import sys

import adp_runtime

HARD = set(adp_runtime.select_worlds("hardest50"))


def outcomes(row):
    """{world: succeeded?} of a one-run-per-world row."""
    return {w["world"]: w["runs"][0]["status"] == "succeeded" for w in row["per_world"]}


def sign_test(a: int, b: int) -> float:
    """Two-sided exact binomial p-value of a vs b discordant pairs under p = 1/2."""
    n = a + b
    if n == 0:
        return 1.0
    k = min(a, b)
    p = sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n
    return min(1.0, 2 * p)


def main(paths):
    rows = []
    for path in paths:
        for row in json.load(open(path)):
            sim = row.get("simulator", "project")
            base = row.get("base", {}).get("name", "-")
            rows.append((f"{sim}:{base}:{row['planner']}:{row['fidelity']}:{row['max_speed']}", row))
    for name, row in rows:
        o = outcomes(row)
        st = {}
        for w in row["per_world"]:
            s = w["runs"][0]["status"]
            st[s] = st.get(s, 0) + 1
        hard = [o[w] for w in o if w in HARD]
        print(f"{name}: success {100 * sum(o.values()) / len(o):.1f} % of {len(o)}, score "
              f"{row['avg_score']:.3f}, hardest-50 {100 * sum(hard) / max(len(hard), 1):.1f} % "
              f"of {len(hard)}, {st}")
    for i, (na, ra) in enumerate(rows):
        for nb, rb in rows[i + 1:]:
            if (ra["planner"], ra["max_speed"]) != (rb["planner"], rb["max_speed"]):
                continue
            a, b = outcomes(ra), outcomes(rb)
            common = sorted(set(a) & set(b))
            both = sum(a[w] and b[w] for w in common)
            only_a = sum(a[w] and not b[w] for w in common)
            only_b = sum(b[w] and not a[w] for w in common)
            print(f"{na} vs {nb}: both {both}, only first {only_a}, only second {only_b}, "
                  f"sign test p = {sign_test(only_a, only_b):.3g}")


if __name__ == "__main__":
    main(sys.argv[1:])
