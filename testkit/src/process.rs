//! Assertions on finished processes and the environment the end-to-end tests need.

use std::process::{Command, Output};

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
