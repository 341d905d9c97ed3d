//! `adp render`: the command line of `eval::render`.

use std::path::PathBuf;

use eval::render::{render, RenderJob};
use eval::{Fidelity, ObstaclePrediction};
use planner::run::CycleDriver;
use planner::{ActionSpace, PlannerKind};

use crate::args::{Setup, WorldData};

/// `adp render`.
#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// World id.
    #[arg(long)]
    pub world: usize,
    /// Planner.
    #[arg(long, value_enum, default_value = "dwa")]
    pub planner: PlannerKind,
    /// Fidelity strategy.
    #[arg(long, value_enum, default_value = "ddp")]
    pub fidelity: Fidelity,
    /// ADP action space (with --fidelity adp).
    #[arg(long, default_value = "decremental")]
    pub action: ActionSpace,
    /// ADP constant-action policy file (see `adp eval --help`).
    #[arg(long)]
    pub policy: Option<PathBuf>,
    /// Speed cap (m/s).
    #[arg(long, default_value_t = 1.5)]
    pub max_speed: f64,
    /// Noise seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Draw the sampled rollouts every this many seconds.
    #[arg(long, default_value_t = 2.0)]
    pub rollouts_every: f64,
    /// Draw the footprint every this many seconds.
    #[arg(long, default_value_t = 0.5)]
    pub footprint_every: f64,
    /// How the planner learns of moving obstacles, as in `adp eval --prediction`; with a
    /// tracker its tracks and their forecasts are drawn (brown).
    #[arg(long, value_enum, default_value = "off")]
    pub prediction: ObstaclePrediction,
    /// Draw a frame strip instead of one picture: this many frames (2 to 24) side by side,
    /// the world at evenly spaced moments from the start to the end of the episode.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Output picture (.png or .svg).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub setup: Setup,
}

/// `adp render`: draws the episode the arguments describe and prints its outcome.
pub fn command(a: &RenderArgs) -> anyhow::Result<()> {
    let cfg = a.setup.eval_config()?;
    let all = a.setup.data.load()?;
    let w = WorldData::get(&all, a.world)?;
    let corrector = (a.prediction == ObstaclePrediction::KfRes)
        .then(|| eval::corrector::load_corrector(cfg.prediction.residual.as_deref()))
        .transpose()?;
    let adp = eval::AdpSetting {
        space: a.action,
        action: match &a.policy {
            Some(p) => eval::policy::load_constant_action(p, a.action)?,
            None => a.action.ddp_action(),
        },
    };
    let job = RenderJob {
        world: w,
        episode: cfg.episode,
        planner: a.planner.build(&cfg.planners(), a.seed),
        schedule: a.fidelity.schedule(&adp)?,
        max_speed: a.max_speed,
        seed: a.seed,
        driver: a.prediction.driver(
            CycleDriver::new(cfg.compute.resolve(a.planner.name())?, cfg.episode.control_dt),
            &cfg,
            corrector.as_ref(),
        ),
        rollout_every_s: a.rollouts_every,
        footprint_every_s: a.footprint_every,
        frames: a.frames,
    };
    let r = render(job, &a.out)?;
    println!(
        "world {} {:?}: time {:.2} s, score {:.3}; picture written to {}",
        r.world,
        r.status,
        r.time_s,
        r.score,
        a.out.display()
    );
    Ok(())
}
