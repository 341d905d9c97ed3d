//! Evaluation of navigation planners on BARN and DynaBARN worlds, as a library.
//!
//! - [`evaluate`]: planners x fidelities x speeds x predictions x lidars over a set of worlds,
//!   run in parallel and reduced to the papers' table (success, time, score, collision,
//!   timeout, and the counted planner work); [`run`] is its entry point, [`eval_run`] one
//!   episode with the seed every comparison shares ([`run_seed`]).
//! - [`policy`]: a trained export or a constant action, loaded and checked against this
//!   build's environment.
//! - [`greedy`]: the greedy monitor a training run starts on its newest policy;
//!   [`selection`]: its held-out selection of the policy to export (`[greedy] select`).
//! - [`calibrate`]: the DDP paper's Table I and the checks of our rows against it.
//! - [`render`]: a picture or a frame strip of one episode.
//! - [`config`]: the evaluation configuration every one of them reads.
//!
//! The `adp` binary's `eval`, `calibrate` and `render` commands parse their arguments into
//! these types and print what they return; another program links this crate to do the same.
//! DWA with DDP's schedule on BARN world 0, one run, as `adp eval --worlds 0` prints it:
//!
//! ```
//! use eval::{AdpSetting, EvalConfig, EvalPlan, Fidelity, LidarOverride, ObstaclePrediction};
//! use planner::{ActionSpace, PlannerKind};
//!
//! let cfg = EvalConfig::load(None)?; // the embedded configs/eval.toml
//! let space = ActionSpace::Decremental;
//! let plan = EvalPlan {
//!     planners: vec![PlannerKind::Dwa],
//!     fidelities: vec![Fidelity::Ddp],
//!     speeds: vec![1.5],
//!     worlds: vec![0],
//!     runs: 1,
//!     trim: 0,
//!     seed: 1,
//!     adp: AdpSetting { space, action: space.ddp_action() },
//!     policy: None,
//!     policy_env: actor::EnvConfig::default(),
//!     predictions: vec![ObstaclePrediction::Off],
//!     lidars: vec![LidarOverride::default()],
//! };
//! let rows = eval::run(&plan, &cfg, sim::catalog::worlds())?;
//! assert_eq!((rows.len(), rows[0].episodes), (1, 1));
//! print!("{}", eval::table(&rows));
//! # Ok::<(), eval::Error>(())
//! ```
//!
//! Every function that can fail returns an [`Error`], whose message is one line that names
//! what failed and where (the file, the world and run, the option or the configuration key).

pub mod calibrate;
pub mod config;
pub mod corrector;
mod error;
pub mod evaluate;
pub mod greedy;
mod greedy_section;
pub mod heldout;
pub mod policy;
pub mod render;
pub mod selection;

pub use config::EvalConfig;
pub use error::{Error, Result};
pub use evaluate::{
    compute_label, eval_run, lidar_label, run, run_seed, summarize, table, AdpSetting, EvalPlan, Fidelity,
    ForecastRmse, LidarOverride, ObstaclePrediction, Row, UnitsPerCycle, WorldRuns, FAILED_RUN_TIME,
};
pub use greedy_section::GreedySection;
