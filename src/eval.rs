//! `adp eval`: the command line of `eval::run`.

use std::path::PathBuf;

use actor::EnvConfig;
use eval::{run, table, AdpSetting, EvalPlan, Fidelity, LidarOverride, ObstaclePrediction};
use planner::{ActionSpace, PlannerKind};

use crate::args::EvalRunArgs;

/// `adp eval`.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Planner(s), comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "dwa")]
    pub planner: Vec<PlannerKind>,
    /// Fidelity strategy (or strategies), comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "ddp")]
    pub fidelity: Vec<Fidelity>,
    /// ADP action space (with --fidelity adp; default: the policy's, else decremental). When
    /// given, the policy's space must be the same.
    #[arg(long)]
    pub action: Option<ActionSpace>,
    /// ADP policy (with --fidelity adp): a trained policy, i.e. the export directory of
    /// `adp export` or `adp train` (or its policy.json), run closed-loop; or a TOML file
    /// with a constant normalized `action = [...]`. Default: the constant action that
    /// reproduces DDP, ADP's initialization.
    #[arg(long)]
    pub policy: Option<PathBuf>,
    /// Speed cap(s) in m/s, comma-separated: one row per value.
    #[arg(long, value_delimiter = ',', default_value = "1.5")]
    pub max_speed: Vec<f64>,
    /// Moving-obstacle prediction(s), comma-separated: one row per value (`off`: none; `kf`:
    /// the tracker's constant-velocity forecast; `kf-res`: kf corrected by PADP's learned
    /// residual corrector, `[prediction] residual`; `padp-path`: kf and PADP's predictive cost in
    /// the global path; `padp`: that and PADP's complexity-adaptive weights, see the
    /// `[prediction]` table; with --fidelity adp and a learned policy, kf exactly when the policy observes tracks).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "off")]
    pub prediction: Vec<ObstaclePrediction>,
    /// Lidar beam count(s) over the field of view, comma-separated: one row per value
    /// (overrides `[episode.lidar]` beams). A trained policy reads any beam count, resampled to
    /// its own layout (docs/guide/simulator/sensing.md#resampling).
    #[arg(long, value_delimiter = ',')]
    pub lidar_beams: Vec<usize>,
    /// Lidar range noise as a fraction of each scan's mean range (replaces `[episode.lidar]`
    /// noise_sigma), comma-separated: one row per value, e.g. 0.05,0.1,0.2.
    #[arg(long, value_delimiter = ',')]
    pub lidar_noise_fraction: Vec<f64>,
    /// Probability that a lidar beam returns nothing (reads max range), comma-separated: one
    /// row per value (overrides `[episode.lidar]` dropout).
    #[arg(long, value_delimiter = ',')]
    pub lidar_dropout: Vec<f64>,
    /// Worlds: comma-separated splits (BARN: fit, val, train = fit + val, test, hardest50, all;
    /// DynaBARN: dynabarn, dynabarn-easy|medium|hard, dynabarn-fit, dynabarn-val,
    /// dynabarn-train, dynabarn-test, ...), ranges (0..50, 300..320) and ids (3,7,305).
    #[arg(long, default_value = "test")]
    pub worlds: String,
    /// Runs per world.
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// Drop this many best and worst runs (by time) of each world before averaging.
    #[arg(long, default_value_t = 0)]
    pub trim: usize,
    #[command(flatten)]
    pub run: EvalRunArgs,
}

/// `adp eval`: runs the plan the arguments describe and prints its table (and writes the rows
/// as JSON with `--out`).
pub fn command(a: &EvalArgs) -> anyhow::Result<()> {
    let mut cfg = a.run.setup.eval_config()?;
    let ids = sim::splits::select(&a.worlds)?;
    if a.runs == 0 {
        anyhow::bail!("--runs must be at least 1");
    }
    if a.policy.is_some() && !a.fidelity.contains(&Fidelity::Adp) {
        anyhow::bail!("--policy applies to --fidelity adp, which is not among the fidelities");
    }
    let all = a.run.setup.data.load()?;
    let ddp = |space: ActionSpace| AdpSetting {
        space,
        action: space.ddp_action(),
    };
    // The source of a trained policy is reported after the run, so that errors stay one line.
    let (adp, net, source) = match &a.policy {
        None => (ddp(a.action.unwrap_or(ActionSpace::Decremental)), None, None),
        Some(p) => match eval::policy::load(p, a.action)? {
            eval::policy::EvalPolicy::Constant { space, action } => {
                (AdpSetting { space, action }, None, None)
            }
            eval::policy::EvalPolicy::Learned(l) => {
                let s = &l.card.source;
                let source = format!(
                    "policy {}: run {}, {} updates, {} action space, layers {:?}, an action \
                     every {} planner cycles, laser clipped at {} m",
                    l.card_path.display(),
                    s.run_id,
                    s.updates,
                    learner::export::space_name(l.space),
                    l.net.dims(),
                    l.env.agent_period_cycles,
                    l.env.laser_clip_m
                );
                // Every row runs on the computer the policy was trained for, unless the
                // command line names another.
                if !a.run.setup.compute_given() {
                    cfg.compute = l.env.compute;
                }
                (ddp(l.space), Some((l.net, l.env)), Some(source))
            }
        },
    };
    let plan = EvalPlan {
        adp,
        policy_env: net.as_ref().map_or_else(EnvConfig::default, |(_, env)| *env),
        policy: net.map(|(net, _)| net),
        planners: a.planner.clone(),
        fidelities: a.fidelity.clone(),
        speeds: a.max_speed.clone(),
        worlds: ids,
        runs: a.runs,
        trim: a.trim,
        seed: a.run.seed,
        predictions: a.prediction.clone(),
        lidars: LidarOverride::combinations(&a.lidar_beams, &a.lidar_noise_fraction, &a.lidar_dropout),
    };
    let rows = a.run.pool()?.install(|| run(&plan, &cfg, &all))?;
    if let Some(source) = source {
        eprintln!("{source}");
    }
    print!("{}", table(&rows));
    a.run.write_json(&rows)
}
