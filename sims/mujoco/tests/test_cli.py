"""`adp-mujoco eval` writes rows in `adp eval --out`'s format, with the project's run seeds,
trim and failure accounting."""

import json

import pytest

pytest.importorskip("adp_runtime")

from adp_mujoco.cli import main, run_seed, summarize  # noqa: E402


def test_run_seed_is_the_projects():
    # eval/src/evaluate.rs run_seed: SplitMix64 of (base, world, run); these values are the
    # Rust function's for the same arguments.
    assert run_seed(0, 0, 0) == 0
    assert run_seed(0, 3, 1) == 5613748509495738422
    assert run_seed(7, 10, 2) == 8665396713404413904


def test_summarize_trims_and_charges_failures():
    runs = [{"status": "succeeded", "time_s": t, "score": 0.5} for t in (5.0, 6.0, 7.0)]
    runs.append({"status": "collided", "time_s": 1.0, "score": 0.0})
    s = summarize([{"world": 0, "runs": runs}], trim=1)
    # Sorted by charged time (a failure counts 50 s): 5, 6, 7, 50 -> keep 6 and 7.
    assert s["episodes"] == 2 and s["success_pct"] == 100.0 and s["avg_time_s"] == 6.5


def test_eval_writes_the_rows(tmp_path, capsys):
    out = tmp_path / "rows.json"
    assert main(["eval", "--worlds", "3", "--runs", "1", "--out", str(out), "--quiet"]) == 0
    assert "| dwa | ddp | 1.5 | 100.00 |" in capsys.readouterr().out
    (row,) = json.loads(out.read_text())
    assert row["simulator"] == "mujoco" and row["planner"] == "dwa" and row["fidelity"] == "ddp"
    assert row["episodes"] == 1 and row["success_pct"] == 100.0
    (w,) = row["per_world"]
    assert w["world"] == 3 and w["runs"][0]["status"] == "succeeded"
    assert set(w["runs"][0]) == {"world", "status", "time_s", "sim_time_s", "score", "distance_m"}
    assert row["units_per_cycle"]["samples"] > 0


def test_eval_refuses_bad_arguments(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "--runs", "2", "--trim", "1"])
    assert main(["eval", "--worlds", "nosuchsplit", "--quiet"]) == 2
    assert "nosuchsplit" in capsys.readouterr().err


def test_a_constant_action_at_ddps_parameters_runs_as_ddp(tmp_path):
    out = tmp_path / "rows.json"
    args = ["eval", "--worlds", "3", "--fidelity", "ddp", "constant", "--constant", "1.7,2.0,20,0",
            "--out", str(out), "--quiet"]
    assert main(args) == 0
    ddp, constant = json.loads(out.read_text())
    assert constant["fidelity"] == "constant" and constant["fidelity_label"].startswith("constant p=1.7")
    assert constant["per_world"] == ddp["per_world"]
    assert main(["eval", "--worlds", "3", "--fidelity", "constant", "--quiet"]) == 2
    assert main(["eval", "--worlds", "3", "--fidelity", "constant", "--constant", "3,2,20,0", "--quiet"]) == 2
