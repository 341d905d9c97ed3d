//! Cluster jobs on a real SLURM: a job written by `adp slurm` trains with every actor task,
//! checkpoints and exports; a job requeued mid-run resumes the same run from its checkpoint; a
//! job whose learner asks for a GPU (the test cluster declares one, `gres gpu:1`) gets it and
//! trains on wgpu while its actors ask for none; sbatch accepts the heterogeneous job of a GPU
//! learner with CPU actor nodes.
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

/// A small job: one node, three actors beside a two-CPU learner, fast leases, short warm-up;
/// `td3` adds lines to `[td3]`.
fn job_config(dir: &Path, td3: &str) -> PathBuf {
    let text = "[run]\nname = \"slurm-test\"\n\n\
                [td3]\nwarmup_steps = 128\nrate_tolerance = 64.0\n"
        .to_owned()
        + td3
        + "\n\
                [service]\nheartbeat_ms = 200\nlease_ttl_ms = 3000\nstatus_every_s = 0.2\n\n\
                [slurm]\nnodes = 1\nactors_per_node = 3\nlearner_node_actors = 3\nlearner_cpus = 2\n\
                learner_mem_mb = 2048\nactor_mem_mb = 512\ntime = \"00:30:00\"\nactor_give_up_s = 60\n\
                actor_grace_s = 30\n";
    let p = dir.join("job.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Writes the job script with `adp slurm` (the job config of `td3` lines, plus `args`) into
/// `dir/job.sbatch`.
fn write_script(dir: &Path, run: &Path, steps: u64, td3: &str, args: &[&str]) -> PathBuf {
    let cfg = job_config(dir, td3);
    let out = Command::new(env!("CARGO_BIN_EXE_adp"))
        .args(["slurm", "--config"])
        .arg(&cfg)
        .args(["--steps", &steps.to_string(), "--run-dir"])
        .arg(run)
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let script = dir.join("job.sbatch");
    std::fs::write(&script, &out.stdout).unwrap();
    script
}

/// Writes the job script with `adp slurm` and submits it; returns the job id.
fn submit(dir: &Path, run: &Path, steps: u64) -> String {
    submit_with(dir, run, steps, "", &[])
}

/// [`submit`] with `td3` lines and `adp slurm` options.
fn submit_with(dir: &Path, run: &Path, steps: u64, td3: &str, args: &[&str]) -> String {
    let script = write_script(dir, run, steps, td3, args);
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
    if let Err(state) = wait_ended(id, run, restarts) {
        panic!("job {id} ended {state}{}", logs(run))
    }
}

/// Polls every 200 ms until the job is COMPLETED with at least `restarts` restarts (`Ok`) or
/// has ended otherwise (`Err` with its state); panics if the watchdog runs out.
fn wait_ended(id: &str, run: &Path, restarts: u32) -> Result<(), String> {
    for _ in 0..9000 {
        let (state, r) = job_state(id);
        match state.as_str() {
            "COMPLETED" if r >= restarts => return Ok(()),
            "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL" | "OUT_OF_MEMORY" | "BOOT_FAIL" | "DEADLINE" => {
                return Err(format!("{state} (restarts {r})"))
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

/// The job's learner asks for the cluster's GPU (`adp slurm --learner-gpus 1`, which also
/// makes it compute on wgpu) while its three actors ask for none: the learner's step gets the
/// GPU, the actors run beside it (were they to wait for the GPU, no step would arrive and the
/// watchdog would fire), and the run trains, checkpoints and exports. Without a Vulkan device
/// the learner cannot start; that skips the test unless ADP_REQUIRE_WGPU=1.
#[test]
fn slurm_job_with_a_gpu_learner_trains_on_wgpu_beside_cpu_actors() {
    if !cluster() {
        return;
    }
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = fresh_dir("slurm-gpu");
    let run = dir.join("run");
    let id = submit_with(
        &dir,
        &run,
        300,
        "batch_size = 32\nactor_warmup_updates = 0\n",
        &["--learner-gpus", "1"],
    );
    let ended = wait_ended(&id, &run, 0);
    let learner_log = std::fs::read_to_string(run.join("logs/learner.log")).unwrap_or_default();
    if ended.is_err() && learner_log.contains("device `wgpu`") {
        assert!(
            std::env::var_os("ADP_REQUIRE_WGPU").is_none_or(|v| v != "1"),
            "ADP_REQUIRE_WGPU=1, but the learner found no wgpu device:{}",
            logs(&run)
        );
        eprintln!("skipped: the learner found no wgpu device");
        return;
    }
    if let Err(state) = ended {
        panic!("job {id} ended {state}{}", logs(&run));
    }
    let out = Command::new("scontrol")
        .args(["show", "job", "-o", &id])
        .output()
        .unwrap();
    let job = String::from_utf8_lossy(&out.stdout);
    assert!(job.contains("gpu:1"), "the job asked for no GPU: {job}");
    assert!(
        learner_log.contains("device=wgpu"),
        "the learner does not say it computes on wgpu:{}",
        logs(&run)
    );
    let s = read_status(&run).unwrap();
    assert!(s.finished && s.inserts >= 300 && s.updates > 0, "{s:?}");
    assert_every_rank_sent_steps(&s, 3, &run);
    assert!(
        run.join("export/policy.onnx").is_file(),
        "no export{}",
        logs(&run)
    );
}

/// A GPU learner with more nodes is a heterogeneous job (a GPU node for the learner, CPU nodes
/// for the other actors). The single-host cluster cannot run one (its components need nodes
/// of their own), but sbatch parses and checks every component's request: `--test-only`.
#[test]
fn sbatch_accepts_the_heterogeneous_job_of_a_gpu_learner() {
    if !cluster() {
        return;
    }
    let dir = fresh_dir("slurm-het");
    let run = dir.join("run");
    let script = write_script(
        &dir,
        &run,
        1000,
        "",
        &["--learner-gpus", "1", "--nodes", "2", "--actors-per-node", "2"],
    );
    let text = std::fs::read_to_string(&script).unwrap();
    assert!(text.contains("#SBATCH hetjob"), "{text}");
    let out = Command::new("sbatch")
        .arg("--test-only")
        .arg(&script)
        .current_dir(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.contains("to start at"),
        "sbatch --test-only refused the heterogeneous job: {err}\n{text}"
    );
}
