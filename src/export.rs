//! `adp export`: write a checkpoint's policy as ONNX, safetensors and a JSON card (the work is
//! done by `learner::export`; this prints what was written).

use std::path::{Path, PathBuf};

use learner::export::{export_checkpoint, space_name};
use planner::ActionSpace;

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
}

/// Export the policy of the checkpoint directory `checkpoint`, trained in `space`, into `out`.
pub fn run(checkpoint: &Path, out: &Path, space: ActionSpace) -> anyhow::Result<()> {
    let summary = export_checkpoint(checkpoint, out, space)?;
    let source = &summary.card.source;
    println!(
        "exported run {} at update {} (policy version {}, {} action space):",
        source.run_id,
        source.updates,
        source.policy_version,
        space_name(space)
    );
    for (path, bytes) in &summary.files {
        println!("  {} ({bytes} bytes)", path.display());
    }
    Ok(())
}
