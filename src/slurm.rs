//! `adp slurm`: prints the sbatch script of a cluster training job ([`train_config::job`]).

use std::path::PathBuf;

use train_config::job::{generate, SlurmOverrides};

/// `adp slurm`.
#[derive(clap::Args, Debug)]
pub struct SlurmArgs {
    /// Run configuration with a `[slurm]` table (default: the embedded configs/slurm.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Overrides of the config's `[slurm]` and `[run]` values.
    #[command(flatten)]
    pub overrides: SlurmOverrides,
    /// Run directory (default: `runs/<name>`; made absolute; its logs/ is created now).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// The adp executable on the compute nodes (default: `[slurm]` adp, else this one).
    #[arg(long)]
    pub adp: Option<PathBuf>,
}

/// `adp slurm`: prints the job script.
pub fn command(a: &SlurmArgs) -> anyhow::Result<()> {
    let script = generate(
        a.config.as_deref(),
        &a.overrides,
        a.run_dir.as_deref(),
        a.adp.as_deref(),
    )?;
    print!("{script}");
    Ok(())
}
