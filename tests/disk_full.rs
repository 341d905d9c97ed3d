//! A full disk under a training run: `adp train` writes its run directory on a small tmpfs,
//! and the test fills that tmpfs right after the first complete checkpoint. Then:
//!
//! - the next periodic checkpoint fails cleanly: the learner logs why ("No space left on
//!   device") and leaves no partial checkpoint behind to hold the space;
//! - the previous checkpoint stays complete and loads;
//! - the run goes on (actors keep sending, the learner keeps storing) and, once space is
//!   free again, checkpoints again and finishes its budget;
//! - a resume from what is left continues the same run.
//!
//! Mounting a tmpfs needs root. Without it the test prints why and skips, unless
//! `ADP_REQUIRE_MOUNT=1` (set by `.ci/run`, which runs as root). Every wait is a bounded poll;
//! nothing asserts a duration.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use learner::{checkpoint, Device};

mod common;
use common::{adp, fresh_dir, status};

/// Polls of a watchdog that should never fire (about five minutes at 100 ms).
const WATCHDOG: usize = 3000;

/// A tmpfs mounted at a directory, unmounted when dropped.
struct Tmpfs(PathBuf);

impl Tmpfs {
    /// Mounts a `size_mb` tmpfs at `dir` (created); `Err` says why it could not.
    fn mount(dir: &Path, size_mb: u32) -> Result<Self, String> {
        std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
        let out = Command::new("mount")
            .args([
                "-t",
                "tmpfs",
                "-o",
                &format!("size={size_mb}m,mode=0700"),
                "tmpfs",
            ])
            .arg(dir)
            .output()
            .map_err(|e| format!("mount: {e}"))?;
        if out.status.success() {
            Ok(Self(dir.to_path_buf()))
        } else {
            Err(String::from_utf8_lossy(&out.stderr).trim().to_owned())
        }
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// The training process; killed when dropped.
struct Run(Child);

impl Drop for Run {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Small networks, a short warm-up and short episodes (the test is about the disk, not about
/// learning); a checkpoint every second, with the replay buffer, two kept.
fn write_config(dir: &Path) -> PathBuf {
    let p = dir.join("disk.toml");
    std::fs::write(
        &p,
        "[env]\nmax_agent_steps = 80\n\n\
         [td3]\nwarmup_steps = 128\nrate_tolerance = 64.0\nbatch_size = 64\n\
         actor_hidden = [64, 64]\ncritic_hidden = [64, 64]\n\n\
         [service]\nheartbeat_ms = 200\nlease_ttl_ms = 3000\nstatus_every_s = 0.2\n\
         checkpoint_every_s = 1.0\ncheckpoint_replay = true\nkeep_checkpoints = 2\n\n\
         [greedy]\nevery_steps = 0\n",
    )
    .unwrap();
    p
}

/// `adp train` of `steps` on `run` with one actor, its stderr in `log`.
fn train(cfg: &Path, run: &Path, steps: u64, resume: bool, log: &Path) -> Run {
    let mut cmd = adp();
    cmd.args([
        "train",
        "--actors",
        "1",
        "--steps",
        &steps.to_string(),
        "--config",
    ])
    .arg(cfg)
    .arg("--out")
    .arg(run);
    if resume {
        cmd.arg("--resume");
    }
    Run(cmd
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap())
}

/// The complete checkpoints of `run`, oldest first.
fn complete(run: &Path) -> Vec<PathBuf> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(run.join("checkpoints"))
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    found.retain(|p| p.join(checkpoint::COMPLETE).is_file());
    found.sort();
    found
}

/// Directories under `run/checkpoints` that are not complete checkpoints (partial saves).
fn partial(run: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(run.join("checkpoints"))
        .map(|d| d.flatten().map(|e| e.path()).collect::<Vec<_>>())
        .unwrap_or_default()
        .into_iter()
        .filter(|p| !p.join(checkpoint::COMPLETE).is_file())
        .collect()
}

/// Polls until `cond` holds; panics with `what` and the log when the watchdog runs out.
fn wait_for(what: &str, log: &Path, mut cond: impl FnMut() -> bool) {
    for _ in 0..WATCHDOG {
        if cond() {
            return;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!(
        "watchdog: {what}\n{}",
        std::fs::read_to_string(log).unwrap_or_default()
    );
}

/// Writes zeros into `path` until the filesystem refuses (ENOSPC); returns the bytes written.
fn fill(path: &Path) -> u64 {
    let mut f = std::fs::File::create(path).unwrap();
    let chunk = vec![0u8; 64 * 1024];
    let mut written = 0;
    loop {
        match f.write(&chunk) {
            Ok(0) => break,
            Ok(n) => written += n as u64,
            Err(e) => {
                assert_eq!(e.raw_os_error(), Some(libc::ENOSPC), "filling the tmpfs: {e}");
                break;
            }
        }
    }
    written
}

#[test]
fn a_full_disk_fails_a_checkpoint_cleanly_and_the_run_goes_on() {
    let dir = fresh_dir("disk-full");
    let run = dir.join("run");
    let mnt = match Tmpfs::mount(&run, 48) {
        Ok(m) => m,
        Err(why) => {
            assert!(
                std::env::var_os("ADP_REQUIRE_MOUNT").is_none_or(|v| v != "1"),
                "ADP_REQUIRE_MOUNT=1, but a tmpfs cannot be mounted: {why}"
            );
            eprintln!("skipped: cannot mount a tmpfs ({why})");
            return;
        }
    };
    let cfg = write_config(&dir);
    let log = dir.join("train.log");
    let budget = 3000;
    let mut first = train(&cfg, &run, budget, false, &log);

    wait_for("a first complete checkpoint", &log, || !complete(&run).is_empty());
    let before = complete(&run);
    let ballast = run.join("ballast");
    assert!(fill(&ballast) > 0);
    let stored_when_full = status(&run).map_or(0, |s| s.inserts);

    // The next periodic checkpoint fails, and says why.
    wait_for("a failed periodic checkpoint", &log, || {
        std::fs::read_to_string(&log).is_ok_and(|t| t.contains("periodic checkpoint failed"))
    });
    let text = std::fs::read_to_string(&log).unwrap();
    let line = text
        .lines()
        .find(|l| l.contains("periodic checkpoint failed"))
        .unwrap();
    assert!(line.contains("No space left on device"), "{line}");
    assert!(
        partial(&run).is_empty(),
        "a failed save left a partial checkpoint: {:?}",
        partial(&run)
    );
    // The checkpoints written before the disk filled are still there, complete, and load.
    for c in &before {
        if c.exists() {
            checkpoint::load(c, &Device::flex()).unwrap_or_else(|e| panic!("{}: {e}", c.display()));
        }
    }
    assert!(
        !complete(&run).is_empty(),
        "no complete checkpoint left while the disk is full"
    );
    // The learner goes on storing steps while the disk is full (status.json cannot be
    // written then: the steps are counted by the next status once there is space).
    assert!(first.0.try_wait().unwrap().is_none(), "the run stopped");

    // Space again: the run checkpoints again and finishes its budget.
    std::fs::remove_file(&ballast).unwrap();
    let code = {
        let mut code = None;
        wait_for("the run to finish", &log, || {
            code = first.0.try_wait().unwrap();
            code.is_some()
        });
        code.unwrap()
    };
    assert!(
        code.success(),
        "{code}\n{}",
        std::fs::read_to_string(&log).unwrap_or_default()
    );
    let done = status(&run).unwrap();
    assert!(done.finished && done.inserts >= budget, "{done:?}");
    assert!(
        done.inserts > stored_when_full,
        "nothing stored after the disk filled"
    );
    let after = complete(&run);
    assert!(
        after.last() > before.last(),
        "no checkpoint after space came back: {after:?}"
    );

    // A resume from what is left continues the same run.
    let log2 = dir.join("resume.log");
    let mut second = train(&cfg, &run, budget + 500, true, &log2);
    let mut code = None;
    wait_for("the resumed run to finish", &log2, || {
        code = second.0.try_wait().unwrap();
        code.is_some()
    });
    let code = code.unwrap();
    assert!(
        code.success(),
        "{code}\n{}",
        std::fs::read_to_string(&log2).unwrap_or_default()
    );
    let resumed = status(&run).unwrap();
    assert_eq!(resumed.run_id, done.run_id, "the same run continues");
    assert!(
        resumed.finished && resumed.inserts >= budget + 500 && resumed.resumed_from.is_some(),
        "{resumed:?}"
    );
    drop(mnt);
}
