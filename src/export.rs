//! `adp export`: write a checkpoint's policy as ONNX, safetensors and a JSON card (the work is
//! done by `learner::export`; this prints what was written).

use std::path::{Path, PathBuf};

use anyhow::bail;
use learner::export::{export_checkpoint, record_trained_for, space_name, TrainedFor};
use planner::{ActionSpace, PlannerKind};

/// `adp export`.
#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    /// Checkpoint directory written by the learner (verified before use).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Output directory (created if needed; existing policy files are replaced).
    #[arg(long)]
    pub out: PathBuf,
    /// Action space the run trained in.
    #[arg(long, default_value = "decremental")]
    pub action: ActionSpace,
    /// The planner the run trained with (`[run] planner` of its config.toml), recorded in the
    /// card so the robot runtime can refuse the policy under another; give with --max-speed.
    #[arg(long, requires = "max_speed")]
    pub planner: Option<PlannerKind>,
    /// The run's speed cap in m/s (`[run] max_speed`), recorded with --planner.
    #[arg(long, requires = "planner")]
    pub max_speed: Option<f64>,
}

/// Export the policy of the checkpoint directory `checkpoint`, trained in `space`, into `out`,
/// recording in the card the planner and speed cap of `trained_for` when given.
pub fn run(
    checkpoint: &Path,
    out: &Path,
    space: ActionSpace,
    trained_for: Option<TrainedFor>,
) -> anyhow::Result<()> {
    if let Some(t) = trained_for {
        if !(t.max_speed.is_finite() && t.max_speed > 0.0) {
            bail!("--max-speed {} must be finite and > 0", t.max_speed);
        }
    }
    let mut summary = export_checkpoint(checkpoint, out, space)?;
    if let Some(t) = trained_for {
        summary.card = record_trained_for(out, t)?;
    }
    let source = &summary.card.source;
    println!(
        "exported run {} at update {} (policy version {}, {} action space):",
        source.run_id,
        source.updates,
        source.policy_version,
        space_name(space)
    );
    if let Some(t) = summary.card.trained_for {
        println!("  trained for {} at {} m/s", t.planner.name(), t.max_speed);
    }
    for (path, bytes) in &summary.files {
        println!("  {} ({bytes} bytes)", path.display());
    }
    Ok(())
}
