//! The PyTorch reference of the TD3 update: `bench/td3_update.py`, embedded, run with a
//! Python the caller names and the thread count of burn's CPU kernels.

use std::path::Path;
use std::process::Command;

use anyhow::{bail, Context};

use crate::tempdir;

/// The script: one TD3 update in PyTorch, the same work and protocol as
/// [`crate::td3::td3_updates`].
const SCRIPT: &str = include_str!("../td3_update.py");

/// PyTorch's figures, as `bench/td3_update.py --json` prints them.
#[derive(serde::Deserialize)]
pub struct TorchTiming {
    /// The torch version.
    pub torch: String,
    /// The threads torch ran on.
    pub threads: usize,
    /// Mean time of one update (ms).
    pub mean_ms: f64,
    /// Median of the critic-only updates (ms).
    pub critic_only_median_ms: f64,
    /// Median of the updates that also step the actor and the targets (ms).
    pub with_actor_median_ms: f64,
}

/// Rayon's thread count (what burn's CPU kernels use), for the PyTorch side.
fn threads() -> usize {
    rayon::current_num_threads()
}

/// Runs the script with `python` for `updates` timed updates and reads its figures.
pub fn pytorch_update(python: &Path, updates: usize) -> anyhow::Result<TorchTiming> {
    let dir = tempdir("torch")?;
    let script = dir.join("td3_update.py");
    std::fs::write(&script, SCRIPT).with_context(|| format!("cannot write {}", script.display()))?;
    let out = Command::new(python)
        .arg(&script)
        .args([
            "--json",
            "--threads",
            &threads().to_string(),
            "--updates",
            &updates.to_string(),
        ])
        .output()
        .with_context(|| format!("cannot run {}", python.display()))?;
    let _ = std::fs::remove_dir_all(&dir);
    if !out.status.success() {
        bail!(
            "{} bench/td3_update.py failed ({}): {}",
            python.display(),
            out.status,
            eval::config::one_line(String::from_utf8_lossy(&out.stderr).trim())
        );
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().last().unwrap_or_default();
    serde_json::from_str(line).with_context(|| format!("bench/td3_update.py printed {line:?}"))
}
