//! What the end-to-end tests (`cli.rs`, `export.rs`, `experiment.rs`, `slurm.rs`, `service.rs`,
//! `faults.rs`, ...) need of this package: the `adp` binary under test, its run directories and
//! learner checkpoints. The helpers that do not depend on this package (assertions on a
//! finished process, the SLURM check, fresh directories, watchdogs) are in `testkit`.
#![allow(dead_code, unused_imports)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

use learner::{checkpoint, seeded_rng, Device, RateLimiter, RunState, Td3, Td3Config};
use learner_service::{read_status, Status};

pub mod certs;
pub use testkit::process::{cluster, one_line_error, stderr, stdout, Needles};

/// The `adp` binary under test.
pub fn adp() -> Command {
    Command::new(env!("CARGO_BIN_EXE_adp"))
}

/// Starts `adp actor` of `rank` on data `plane` (auto, grpc or shm) against the learner at
/// `addr`, its output discarded.
pub fn spawn_actor(addr: &str, token: &Path, rank: u32, plane: &str) -> Child {
    adp()
        .args(["actor", "--learner", addr, "--data-plane", plane])
        .args(["--rank", &rank.to_string(), "--token-file"])
        .arg(token)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// Runs `adp ARGS` to completion.
pub fn run(args: &[&str]) -> Output {
    adp().args(args).output().expect("adp binary runs")
}

/// An empty directory `<target>/tmp/<name>-<pid>`.
pub fn fresh_dir(name: &str) -> PathBuf {
    testkit::fresh_dir_in(Path::new(env!("CARGO_TARGET_TMPDIR")), name)
}

/// The run's `status.json`, when it is there and readable.
pub fn status(run: &Path) -> Option<Status> {
    read_status(run).ok()
}

/// How many messages of `kind` the learner refused.
pub fn refused(s: &Status, kind: &str) -> u64 {
    s.refused.iter().find(|(k, _)| k == kind).map_or(0, |r| r.1)
}

/// Writes a learner checkpoint to `dir` through the learner API, the way a run does: TD3 from
/// `config`, set up by `prepare`, with the run state of run `run_id` recording `environment`.
pub fn save_checkpoint(
    dir: &Path,
    config: &Td3Config,
    run_id: &str,
    environment: serde_json::Value,
    prepare: impl FnOnce(&mut Td3),
) {
    let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
    prepare(&mut td3);
    let run = RunState {
        run_id: run_id.into(),
        rate: RateLimiter::new(config),
        sampler_rng: seeded_rng(config.seed, 2),
        policy_version: 1,
        extra: serde_json::Value::Null,
        environment,
    };
    checkpoint::save(dir, &td3, &run).unwrap();
}
