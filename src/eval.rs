//! `adp eval`: the command line of `eval::run`.

use std::path::PathBuf;

use std::fmt::Write as _;

use actor::EnvConfig;
use eval::{run, summarize, table, AdpSetting, EvalPlan, Fidelity, LidarOverride, ObstaclePrediction, Row};
use experiment::stats::bootstrap_mean;
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
    if let Some(paired) = paired_table(&rows, a.trim) {
        print!("\n{paired}");
    }
    a.run.write_json(&rows)
}

/// Resamples of the paired bootstrap under `adp eval`'s table.
const RESAMPLES: usize = 10_000;
/// The bootstrap's seed, so the printed intervals reproduce.
const PAIRED_SEED: u64 = 3;

/// Every row after the first against the first, paired over worlds (every row runs the same
/// worlds with the same run seeds): per world, each row's runs trimmed by `trim` as the table
/// trims them and averaged, then the differences averaged over the worlds with a 95 %
/// percentile-bootstrap interval (seeded), and the worlds where the row scores higher, lower
/// or the same. `None` with fewer than two rows.
pub fn paired_table(rows: &[Row], trim: usize) -> Option<String> {
    let (base, others) = rows.split_first()?;
    if others.is_empty() {
        return None;
    }
    let label = |r: &Row| {
        let lidar = r
            .lidar
            .as_ref()
            .map_or_else(String::new, |l| format!(" {}", eval::lidar_label(l)));
        format!(
            "{} {} {:.1}{lidar}",
            r.planner.name(),
            r.fidelity_label,
            r.max_speed
        )
    };
    // (world, success 0..1, score) per world after trimming.
    let per_world = |r: &Row| -> Vec<(usize, f64, f64)> {
        r.per_world
            .iter()
            .map(|w| {
                let (success, _, score, _, _, _) = summarize(std::slice::from_ref(w), trim);
                (w.world, success / 100.0, score)
            })
            .collect()
    };
    let b = per_world(base);
    let mut out = format!(
        "Paired against the first row ({}), over {} worlds: mean difference and 95 % bootstrap \
         interval ({RESAMPLES} resamples of the worlds)\n\n\
         | row | score − first | success − first (points) | worlds higher / lower / equal in score |\n\
         |---|---|---|---|\n",
        label(base),
        b.len()
    );
    for r in others {
        let o = per_world(r);
        if o.iter().map(|x| x.0).ne(b.iter().map(|x| x.0)) {
            let _ = writeln!(out, "| {} | – (other worlds) | – | – |", label(r));
            continue;
        }
        let d_score: Vec<f64> = o.iter().zip(&b).map(|(x, y)| x.2 - y.2).collect();
        let d_success: Vec<f64> = o.iter().zip(&b).map(|(x, y)| 100.0 * (x.1 - y.1)).collect();
        let s = bootstrap_mean(&d_score, RESAMPLES, 0.95, PAIRED_SEED);
        let c = bootstrap_mean(&d_success, RESAMPLES, 0.95, PAIRED_SEED ^ 1);
        let count = |f: fn(f64) -> bool| d_score.iter().filter(|&&d| f(d)).count();
        let _ = writeln!(
            out,
            "| {} | {:+.4} [{:+.4}, {:+.4}] | {:+.2} [{:+.2}, {:+.2}] | {} / {} / {} |",
            label(r),
            s.mean,
            s.lo,
            s.hi,
            c.mean,
            c.lo,
            c.hi,
            count(|d| d > 1e-12),
            count(|d| d < -1e-12),
            count(|d| d.abs() <= 1e-12)
        );
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use eval::WorldRuns;
    use sim::{EpisodeResult, Status};

    fn row(fidelity: &str, worlds: &[(usize, [f64; 3])]) -> Row {
        let run = |world: usize, score: f64| EpisodeResult {
            world,
            status: if score > 0.0 {
                Status::Succeeded
            } else {
                Status::Collided
            },
            time_s: 10.0,
            sim_time_s: 10.0,
            score,
            distance_m: 0.0,
        };
        let per_world: Vec<WorldRuns> = worlds
            .iter()
            .map(|&(w, scores)| WorldRuns {
                world: w,
                runs: scores.iter().map(|&s| run(w, s)).collect(),
            })
            .collect();
        Row {
            planner: PlannerKind::Dwa,
            fidelity: Fidelity::Ddp,
            fidelity_label: fidelity.into(),
            prediction: ObstaclePrediction::Off,
            max_speed: 1.5,
            lidar: None,
            success_pct: 0.0,
            avg_time_s: 0.0,
            avg_score: 0.0,
            collision_pct: 0.0,
            timeout_pct: 0.0,
            episodes: 0,
            check_points_per_cycle: 0.0,
            plan_ms_per_cycle: 0.0,
            compute_model: "free".into(),
            units_per_cycle: eval::UnitsPerCycle::default(),
            modelled_ms_per_cycle: 0.0,
            samples_evaluated_pct: 0.0,
            truncated_cycles_pct: 0.0,
            late_cycles_pct: 0.0,
            pressure_modes_pct: None,
            forecast: None,
            per_world,
        }
    }

    /// The first row is the baseline; the others' differences are per world after trimming
    /// as the table does (runs sorted by time, a failure charged 50 s, here one dropped from
    /// each end of three), paired, with the worlds each row scores higher, lower and equal.
    #[test]
    fn rows_are_paired_with_the_first_over_worlds_after_trimming() {
        let base = row(
            "ddp",
            &[(1, [0.4, 0.0, 0.5]), (2, [0.3, 0.3, 0.3]), (3, [0.0, 0.2, 0.1])],
        );
        let other = row(
            "adp",
            &[(1, [0.5, 0.45, 0.0]), (2, [0.3, 0.3, 0.3]), (3, [0.0, 0.0, 0.0])],
        );
        assert!(paired_table(std::slice::from_ref(&base), 1).is_none());
        let t = paired_table(&[base, other], 1).unwrap();
        // Kept runs: base 0.5, 0.3, 0.1 (its failures sort last); other 0.45, 0.3 and a
        // failure: differences -0.05, 0, -0.1.
        assert!(t.contains("over 3 worlds"), "{t}");
        assert!(t.contains("| dwa adp 1.5 | -0.0500 ["), "{t}");
        assert!(t.contains("| 0 / 2 / 1 |"), "{t}");
        // Success: only world 3's kept run fails for the other row (-100 points).
        assert!(t.contains("| -33.33 ["), "{t}");
    }
}
