//! Cluster jobs on a real SLURM: a job written by `adp slurm` trains with every actor task,
//! checkpoints and exports; a job requeued mid-run resumes the same run from its checkpoint.
//!
//! They need a running cluster named by `SLURM_CONF` (`scripts/slurm-cluster.sh start DIR`
//! starts a single-host one). Without one they print why and skip, unless
//! `ADP_REQUIRE_SLURM=1` (set by `.ci/run`, which starts the cluster), where that is a failure.
//! Waits are bounded by a watchdog (a number of polls); nothing asserts a duration.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::time::Duration;

use learner_service::{read_status, Status};

mod common;
use common::{cluster, fresh_dir};

/// The jobs share the test cluster's CPUs: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// A small job: one node, three actors beside a two-CPU learner, fast leases, short warm-up.
fn job_config(dir: &Path) -> PathBuf {
    let text = "[run]\nname = \"slurm-test\"\n\n\
                [td3]\nwarmup_steps = 128\nrate_tolerance = 64.0\n\n\
                [service]\nheartbeat_ms = 200\nlease_ttl_ms = 3000\nstatus_every_s = 0.2\n\n\
                [slurm]\nnodes = 1\nactors_per_node = 3\nlearner_node_actors = 3\nlearner_cpus = 2\n\
                learner_mem_mb = 2048\nactor_mem_mb = 512\ntime = \"00:30:00\"\nactor_give_up_s = 60\n\
                actor_grace_s = 30\n";
    let p = dir.join("job.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Writes the job script with `adp slurm` and submits it; returns the job id.
fn submit(dir: &Path, run: &Path, steps: u64) -> String {
    let cfg = job_config(dir);
    let out = Command::new(env!("CARGO_BIN_EXE_adp"))
        .args(["slurm", "--config"])
        .arg(&cfg)
        .args(["--steps", &steps.to_string(), "--run-dir"])
        .arg(run)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let script = dir.join("job.sbatch");
    std::fs::write(&script, &out.stdout).unwrap();
    let out = Command::new("sbatch")
        .arg("--parsable")
        .arg(&script)
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "sbatch: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let id = String::from_utf8_lossy(&out.stdout);
    id.trim().split(';').next().unwrap().to_owned()
}

/// `(JobState, Restarts)` of job `id`.
fn job_state(id: &str) -> (String, u32) {
    let out = Command::new("scontrol")
        .args(["show", "job", "-o", id])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let field = |name: &str| {
        text.split_whitespace()
            .find_map(|kv| kv.strip_prefix(name))
            .unwrap_or("")
            .to_owned()
    };
    (field("JobState="), field("Restarts=").parse().unwrap_or(0))
}

/// Everything the job and its tasks logged, for failure messages.
fn logs(run: &Path) -> String {
    let mut all = String::new();
    if let Ok(entries) = std::fs::read_dir(run.join("logs")) {
        for e in entries.flatten() {
            let text = std::fs::read_to_string(e.path()).unwrap_or_default();
            let tail: String = text.lines().rev().take(15).collect::<Vec<_>>().join("\n");
            all += &format!("\n== {} (last lines, newest first)\n{tail}", e.path().display());
        }
    }
    all
}

/// Polls every 200 ms until the job is COMPLETED with at least `restarts` restarts; panics
/// with the logs if it ends otherwise or the watchdog runs out.
fn wait_completed(id: &str, run: &Path, restarts: u32) {
    for _ in 0..9000 {
        let (state, r) = job_state(id);
        match state.as_str() {
            "COMPLETED" if r >= restarts => return,
            "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL" | "OUT_OF_MEMORY" | "BOOT_FAIL" | "DEADLINE" => {
                panic!("job {id} ended {state} (restarts {r}){}", logs(run))
            }
            _ => std::thread::sleep(Duration::from_millis(200)),
        }
    }
    let _ = Command::new("scancel").arg(id).status();
    panic!("watchdog: job {id} did not complete{}", logs(run));
}

fn assert_every_rank_sent_steps(s: &Status, ranks: u32, run: &Path) {
    for rank in 0..ranks {
        let n = s.rank_steps.iter().find(|(r, _)| *r == rank).map_or(0, |r| r.1);
        assert!(
            n > 0,
            "actor rank {rank} sent no steps: {:?}{}",
            s.rank_steps,
            logs(run)
        );
    }
}

#[test]
fn slurm_job_trains_with_every_actor_task_and_exports() {
    if !cluster() {
        return;
    }
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = fresh_dir("slurm-job");
    let run = dir.join("run");
    let id = submit(&dir, &run, 600);
    wait_completed(&id, &run, 0);
    let s = read_status(&run).unwrap();
    assert!(s.finished && s.inserts >= 600, "{s:?}");
    assert!(s.replay_len as u64 >= s.inserts, "{s:?}");
    assert_eq!(s.episodes_verified, s.episodes, "{s:?}");
    assert_eq!(s.episodes_mismatched, 0, "{s:?}");
    assert_every_rank_sent_steps(&s, 3, &run);
    let checkpoints: Vec<_> = std::fs::read_dir(run.join("checkpoints"))
        .unwrap()
        .flatten()
        .collect();
    assert!(!checkpoints.is_empty(), "no checkpoint{}", logs(&run));
    assert!(
        run.join("export/policy.onnx").is_file(),
        "no export{}",
        logs(&run)
    );
}

#[test]
fn requeued_slurm_job_resumes_the_same_run() {
    if !cluster() {
        return;
    }
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = fresh_dir("slurm-requeue");
    let run = dir.join("run");
    let budget = 1500;
    let id = submit(&dir, &run, budget);
    let mut before: Option<Status> = None;
    for _ in 0..6000 {
        if let Some(s) = read_status(&run).ok().filter(|s| s.inserts >= 300) {
            before = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let before = before.unwrap_or_else(|| panic!("watchdog: no training progress{}", logs(&run)));
    assert!(
        before.inserts < budget,
        "the run finished before the requeue: {before:?}"
    );
    let out = Command::new("scontrol").args(["requeue", &id]).output().unwrap();
    assert!(
        out.status.success(),
        "scontrol requeue: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    wait_completed(&id, &run, 1);

    let after = read_status(&run).unwrap();
    assert_eq!(
        after.run_id, before.run_id,
        "a requeued job continues the same run"
    );
    assert_ne!(
        after.incarnation, before.incarnation,
        "a new learner process served it"
    );
    assert!(after.finished && after.inserts >= budget, "{after:?}");
    assert!(
        after.steps_received > before.steps_received && after.replay_len >= before.replay_len,
        "the step counters and the replay buffer continued: {after:?}"
    );
    assert_every_rank_sent_steps(&after, 3, &run);
    // The requeued learner resumed the run (same run id, above) from a checkpoint holding at
    // least what was stored before the requeue.
    let resumed = after
        .resumed_from
        .as_ref()
        .unwrap_or_else(|| panic!("the requeued learner did not resume: {after:?}{}", logs(&run)));
    assert!(
        resumed.inserts >= before.inserts,
        "resumed from {resumed:?}, but {} steps were stored before the requeue",
        before.inserts
    );
}
