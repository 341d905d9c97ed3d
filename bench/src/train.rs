//! `adp bench train`: `adp train` end to end (learner and actor processes at one update per
//! agent step), agent steps and updates per second once training has started.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use learner_service::read_status;

use crate::{figure, tempdir, Figure};

/// The `train` part's figures: runs `adp train` (the executable `adp`) for `steps` agent steps
/// with `actors` actor processes (0: its default) and the embedded config, and watches
/// `status.json`: the rate counts from the first sample with updates to the last before the
/// run finished.
pub fn run(adp: &Path, steps: u64, actors: u32) -> anyhow::Result<Vec<Figure>> {
    let dir = tempdir("train")?;
    let run = dir.join("run");
    let log = std::fs::File::create(dir.join("train.log"))?;
    let mut cmd = Command::new(adp);
    cmd.args(["train", "--steps", &steps.to_string(), "--out"])
        .arg(&run);
    if actors > 0 {
        cmd.args(["--actors", &actors.to_string()]);
    }
    let started = Instant::now();
    let mut child = cmd
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .with_context(|| format!("cannot start {} train", adp.display()))?;
    let mut first: Option<(Instant, u64, u64)> = None;
    let mut last: Option<(Instant, u64, u64)> = None;
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        std::thread::sleep(Duration::from_millis(500));
        if let Ok(s) = read_status(&run) {
            if s.updates > 0 && !s.finished {
                let now = (Instant::now(), s.inserts, s.updates);
                first.get_or_insert(now);
                last = Some(now);
            }
        }
    };
    let wall = started.elapsed().as_secs_f64();
    if !status.success() {
        bail!(
            "adp train failed ({status}); its log is {}",
            dir.join("train.log").display()
        );
    }
    let s = read_status(&run)?;
    let (Some(a), Some(b)) = (first, last) else {
        bail!("the run finished before a training window could be measured; raise --train-steps");
    };
    let secs = b.0.duration_since(a.0).as_secs_f64().max(1e-9);
    let figures = vec![
        figure(
            "end-to-end agent steps/s while training",
            (b.1 - a.1) as f64 / secs,
            "1/s",
        )
        .at_least(40.0),
        figure(
            "end-to-end updates/s while training",
            (b.2 - a.2) as f64 / secs,
            "1/s",
        ),
        figure(
            format!("end-to-end run of {} agent steps, wall", s.inserts),
            wall,
            "s",
        ),
    ];
    let _ = std::fs::remove_dir_all(&dir);
    Ok(figures)
}
