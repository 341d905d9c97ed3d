//! `adp tracks log` and `adp tracks fit`: the data and the training of PADP's residual
//! corrector of the Kalman forecast (`planner::residual`, `planner::residual_fit`).
//!
//! `log` drives a planner (DWA-DDP by default) with the tracker on the given worlds and writes
//! every sample (`planner::residual_fit::Sample`) as one JSON line; `fit` trains a corrector
//! on such a file and writes it as JSON, for `adp eval --prediction kf-res` (`[prediction]
//! residual`). Neither touches a held-out world: `log` refuses any world of the `test`,
//! `hardest50` or `dynabarn-test` splits, and `fit` refuses samples from them.

use std::io::{BufRead, BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use rayon::prelude::*;

use actor::closed_loop::{self, Chooser, Step};
use planner::residual::{STEPS, STEP_S};
use planner::residual_fit::{fit, FitSettings, Sample};
use planner::run::CycleDriver;
use planner::{PlannerKind, Schedule, TrackingConfig};

use crate::args::EvalRunArgs;
use eval::{eval_run, run_seed};

/// `adp tracks`.
#[derive(clap::Subcommand, Debug)]
pub enum TracksCmd {
    /// Drive a planner with the obstacle tracker on training worlds and log the residual
    /// corrector's samples (features and the truth's offsets from the constant-velocity
    /// forecast at the 7 steps of 0.4 s), one JSON object per line.
    Log(LogArgs),
    /// Train the residual corrector (an MLP, minibatch Adam on the squared error) on logged
    /// samples, split by world into training and validation, and write it as JSON.
    Fit(FitArgs),
}

impl TracksCmd {
    /// Runs the subcommand.
    pub fn run(&self) -> anyhow::Result<()> {
        match self {
            TracksCmd::Log(a) => log(a),
            TracksCmd::Fit(a) => fit_command(a),
        }
    }
}

/// `adp tracks log`.
#[derive(clap::Args, Debug)]
pub struct LogArgs {
    /// Worlds (splits, ranges, ids as for `adp eval`); no held-out world.
    #[arg(long, default_value = "dynabarn-fit")]
    pub worlds: String,
    /// Runs per world (each its own seed: other obstacle phases and noise).
    #[arg(long, default_value_t = 1)]
    pub runs: usize,
    /// The planner that drives (with the DDP schedule).
    #[arg(long, value_enum, default_value = "dwa")]
    pub planner: PlannerKind,
    /// Speed cap (m/s).
    #[arg(long, default_value_t = 1.5)]
    pub max_speed: f64,
    #[command(flatten)]
    pub run: EvalRunArgs,
}

/// `adp tracks fit`.
#[derive(clap::Args, Debug)]
pub struct FitArgs {
    /// The samples (`adp tracks log --out`).
    #[arg(long)]
    pub data: PathBuf,
    /// Where to write the corrector (JSON).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the initialization, the split by world and the shuffling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Passes over the training samples.
    #[arg(long, default_value_t = 30)]
    pub epochs: usize,
    /// Samples per Adam step.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Adam's step size.
    #[arg(long, default_value_t = 1e-3)]
    pub learning_rate: f64,
    /// Share of the worlds held out for validation.
    #[arg(long, default_value_t = 0.2)]
    pub val_fraction: f64,
}

/// `adp tracks log`: runs the episodes in parallel and writes their samples in world, run
/// order to `--out` (required).
fn log(a: &LogArgs) -> anyhow::Result<()> {
    let Some(out) = &a.run.out else {
        bail!("adp tracks log needs --out FILE (the samples, one JSON object per line)");
    };
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let ids = sim::splits::select(&a.worlds)?;
    let held_out = sim::splits::held_out_worlds();
    if let Some(w) = ids.iter().find(|w| held_out.binary_search(w).is_ok()) {
        bail!(
            "--worlds {}: world {w} is held out for testing (test, hardest50, dynabarn-test); \
             log training worlds only, e.g. dynabarn-fit",
            a.worlds
        );
    }
    let cfg = a.run.setup.eval_config()?;
    if !(a.max_speed > 0.0 && a.max_speed <= cfg.episode.robot.max_v) {
        bail!(
            "--max-speed {} must be in (0, {}] m/s",
            a.max_speed,
            cfg.episode.robot.max_v
        );
    }
    let all = a.run.setup.data.load()?;
    let compute = cfg.compute.resolve(a.planner.name())?;
    let jobs: Vec<(usize, usize)> = ids
        .iter()
        .flat_map(|&w| (0..a.runs).map(move |r| (w, r)))
        .collect();
    let schedule = Schedule::ddp_default();
    let started = std::time::Instant::now();
    let per_run: Vec<Vec<Sample>> = a.run.pool()?.install(|| {
        jobs.par_iter()
            .map(|&(w, r)| {
                let world = crate::args::WorldData::get(&all, w)?;
                let run = eval_run(&cfg, world, a.planner, a.max_speed, run_seed(a.run.seed, w, r));
                let mut driver = CycleDriver::new(compute, cfg.episode.control_dt)
                    .with_tracking(TrackingConfig::default())
                    .with_samples();
                let chooser = Chooser::Fixed {
                    schedule: &schedule,
                    driver: &mut driver,
                };
                closed_loop::run(run, chooser, |_: &Step<'_>| Ok::<(), anyhow::Error>(()))
                    .with_context(|| format!("world {w}, run {r}"))?;
                Ok(driver.take_samples())
            })
            .collect::<anyhow::Result<_>>()
    })?;
    let file = std::fs::File::create(out).with_context(|| format!("cannot write {}", out.display()))?;
    let mut w = BufWriter::new(file);
    let mut n = 0;
    for s in per_run.iter().flatten() {
        serde_json::to_writer(&mut w, s)?;
        w.write_all(b"\n")?;
        n += 1;
    }
    w.flush()
        .with_context(|| format!("cannot write {}", out.display()))?;
    let gated = per_run
        .iter()
        .flatten()
        .filter(|s| s.curvature >= planner::residual::PAPER_THRESHOLD_RAD)
        .count();
    eprintln!(
        "{n} samples ({gated} with curvature >= {} rad) from {} episodes on {} worlds in {:.0} s -> {}",
        planner::residual::PAPER_THRESHOLD_RAD,
        jobs.len(),
        ids.len(),
        started.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

/// Reads a samples file; an error names the file and the line.
fn read_samples(path: &Path) -> anyhow::Result<Vec<Sample>> {
    let file = std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.with_context(|| format!("cannot read {}", path.display()))?;
        if line.trim().is_empty() {
            continue;
        }
        let s: Sample = serde_json::from_str(&line)
            .with_context(|| format!("{} line {}: not a sample", path.display(), i + 1))?;
        out.push(s);
    }
    Ok(out)
}

/// `adp tracks fit`: trains, prints the loss per epoch and the validation RMSE per step, and
/// writes the corrector.
fn fit_command(a: &FitArgs) -> anyhow::Result<()> {
    let samples = read_samples(&a.data)?;
    let held_out = sim::splits::held_out_worlds();
    if let Some(s) = samples.iter().find(|s| held_out.binary_search(&s.world).is_ok()) {
        bail!(
            "{}: has samples of world {}, which is held out for testing (test, hardest50, \
             dynabarn-test); fit on training worlds only",
            a.data.display(),
            s.world
        );
    }
    let settings = FitSettings {
        seed: a.seed,
        epochs: a.epochs,
        batch: a.batch,
        learning_rate: a.learning_rate,
        val_fraction: a.val_fraction,
        ..FitSettings::default()
    };
    let started = std::time::Instant::now();
    let fitted = fit(
        &samples,
        &settings,
        &a.data.display().to_string(),
        |e, train, val| {
            println!("epoch {e:>3}: train {train:.4}, val {val:.4} (MSE, normalized)");
        },
    )?;
    let c = &fitted.corrector;
    let t = &c.trained;
    println!(
        "{} training samples from worlds {:?}, {} validation samples from worlds {:?}; {:.1} s",
        t.samples[0],
        t.train_worlds,
        t.samples[1],
        t.val_worlds,
        started.elapsed().as_secs_f64()
    );
    let v = &fitted.val;
    println!(
        "validation RMSE (m) per step; gain {}, clip {} m, gate chi >= {} rad open on {:.1} % of the samples",
        c.gain,
        c.clip_m,
        c.threshold_rad,
        100.0 * v.gated_share
    );
    print!("{:<22}", "tau (s)");
    for k in 0..STEPS {
        print!("{:>7.1}", (k + 1) as f64 * STEP_S);
    }
    println!("{:>8}", "mean");
    for (name, row) in [
        ("cv (kf)", v.cv),
        ("cv + residual, gated", v.gated),
        ("cv + residual, all", v.ungated),
    ] {
        print!("{name:<22}");
        for x in row {
            print!("{x:>7.3}");
        }
        let mean = (row.iter().map(|x| x * x).sum::<f64>() / STEPS as f64).sqrt();
        println!("{mean:>8.3}");
    }
    let text = serde_json::to_string(&c.to_file())?;
    std::fs::write(&a.out, text + "\n").with_context(|| format!("cannot write {}", a.out.display()))?;
    println!("-> {}", a.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn held_out_worlds_are_refused() {
        let cli = <crate::cli::Cli as clap::Parser>::try_parse_from([
            "adp",
            "tracks",
            "log",
            "--worlds",
            "dynabarn-fit,322",
            "--out",
            "/dev/null",
        ])
        .unwrap();
        let crate::cli::Cmd::Tracks { cmd } = cli.cmd else {
            panic!("not tracks");
        };
        let e = cmd.run().unwrap_err().to_string();
        assert!(e.contains("world 322 is held out"), "{e}");
    }
}
