//! `adp calibrate`: the command line of `eval::calibrate`.

use anyhow::Context;
use eval::calibrate::{checks, compare, paper_row, render, PaperRow, Report, TABLE_I};
use eval::{AdpSetting, EvalPlan};
use planner::ActionSpace;

use crate::args::EvalRunArgs;

/// `adp calibrate`.
#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {
    /// Rows to run, comma-separated labels (default: all seven).
    #[arg(long, value_delimiter = ',')]
    pub rows: Vec<String>,
    /// Speed caps, comma-separated (default: the paper's 1.0, 1.5, 2.0).
    #[arg(long, value_delimiter = ',', default_value = "1.0,1.5,2.0")]
    pub max_speed: Vec<f64>,
    /// Worlds: comma-separated splits, ranges and ids, as for `adp eval`.
    #[arg(long, default_value = "all")]
    pub worlds: String,
    /// Runs per world.
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    #[command(flatten)]
    pub run: EvalRunArgs,
}

/// `adp calibrate`: runs the chosen rows and prints the comparison and the checks.
pub fn command(a: &CalibrateArgs) -> anyhow::Result<()> {
    let cfg = a.run.setup.eval_config()?;
    let ids = sim::splits::select(&a.worlds)?;
    let chosen: Vec<&PaperRow> = if a.rows.is_empty() {
        TABLE_I.iter().collect()
    } else {
        a.rows
            .iter()
            .map(|r| {
                paper_row(r).with_context(|| {
                    let labels: Vec<&str> = TABLE_I.iter().map(|p| p.label).collect();
                    format!("--rows: unknown row `{r}` (expected {})", labels.join(", "))
                })
            })
            .collect::<anyhow::Result<_>>()?
    };
    let all = a.run.setup.data.load()?;
    let space = ActionSpace::Decremental;
    let pool = a.run.pool()?;
    let t0 = std::time::Instant::now();
    let mut eval_rows = Vec::new();
    // One eval per row keeps the work to exactly the rows asked for.
    for row in &chosen {
        let plan = EvalPlan {
            adp: AdpSetting {
                space,
                action: space.ddp_action(),
            },
            policy: None,
            policy_env: actor::EnvConfig::default(),
            planners: vec![row.planner],
            fidelities: vec![row.fidelity],
            speeds: a.max_speed.clone(),
            worlds: ids.clone(),
            runs: a.runs,
            trim: 0,
            seed: a.run.seed,
            predictions: vec![eval::ObstaclePrediction::Off],
            lidars: vec![eval::LidarOverride::default()],
        };
        eprintln!("{}:", row.label);
        eval_rows.extend(pool.install(|| eval::run(&plan, &cfg, &all))?);
    }
    let cells = compare(&eval_rows);
    let report = Report {
        checks: checks(&cells),
        cells,
    };
    println!(
        "Table I protocol on the {} profile: {} worlds x {} runs, {:.0} s",
        cfg.episode.profile.name(),
        ids.len(),
        a.runs,
        t0.elapsed().as_secs_f64()
    );
    print!("{}", render(&report));
    println!("\nour rows with their cost:\n");
    print!("{}", eval::table(&eval_rows));
    if a.run.out.is_some() {
        a.run.write_json(&serde_json::json!({
            "profile": cfg.episode.profile.name(),
            "dynamics": cfg.episode.resolved_dynamics()?,
            "worlds": ids.len(),
            "runs": a.runs,
            "report": report,
            "rows": eval_rows,
        }))?;
    }
    Ok(())
}
