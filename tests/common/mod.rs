//! Helpers shared by the end-to-end tests (`cli.rs`, `export.rs`, `experiment.rs`, `slurm.rs`,
//! `service.rs`, `faults.rs`), defined once. Each test file uses a part of them.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

use learner::{checkpoint, seeded_rng, Device, RateLimiter, RunState, Td3, Td3Config};
use learner_service::{read_status, Status};

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

/// The standard output of `o`, as text.
pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The standard error of `o`, as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// What a one-line error must contain: one string or all of a list.
pub trait Needles {
    /// The strings.
    fn needles(&self) -> Vec<&str>;
}

impl Needles for &str {
    fn needles(&self) -> Vec<&str> {
        vec![self]
    }
}

impl<const N: usize> Needles for &[&str; N] {
    fn needles(&self) -> Vec<&str> {
        self.to_vec()
    }
}

/// Asserts that `o` failed with exactly one non-empty line on stderr, containing `needles`.
pub fn one_line_error(o: &Output, needles: impl Needles) {
    assert!(
        !o.status.success(),
        "expected failure, got success: {}",
        stdout(o)
    );
    let err = stderr(o);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line expected, got: {err}");
    for needle in needles.needles() {
        assert!(lines[0].contains(needle), "`{needle}` not in: {err}");
    }
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

/// Whether a SLURM cluster answers (`SLURM_CONF`; `scripts/slurm-cluster.sh start DIR` starts a
/// single-host one); panics when one is required (`ADP_REQUIRE_SLURM=1`, set by `.ci/run`) and
/// does not.
pub fn cluster() -> bool {
    let conf = std::env::var_os("SLURM_CONF");
    let answers = conf.is_some()
        && Command::new("sinfo")
            .arg("-h")
            .output()
            .is_ok_and(|o| o.status.success());
    if !answers {
        let why = match conf {
            None => "SLURM_CONF is not set (start a cluster with scripts/slurm-cluster.sh start DIR)",
            Some(_) => "`sinfo` does not answer for SLURM_CONF",
        };
        assert!(
            std::env::var("ADP_REQUIRE_SLURM").as_deref() != Ok("1"),
            "ADP_REQUIRE_SLURM=1 but {why}"
        );
        eprintln!("SKIPPED: no SLURM cluster: {why}");
    }
    answers
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
