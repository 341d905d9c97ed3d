//! What a stage costs: its work units, its cost class and the core-seconds per unit measured
//! by the stages the store already holds, for `--plan` and the progress line's ETA.
//!
//! Pure: the measured records come in as [`StageMeta`] values.

use std::collections::BTreeMap;
use std::path::Path;

use super::config::{planner_name, space_label, Experiment};
use super::controls::halving;
use super::plan::{stages, Stage, SweepWho, Sweeps};
use super::recipe::Kind;
use super::store::{class_of, cost_class, train_class, Layout, StageMeta};

/// The kind of a stage's result.
pub fn kind(stage: &Stage) -> Kind {
    match stage {
        Stage::Train { .. } => Kind::Train,
        Stage::Search { .. } => Kind::Search,
        _ => Kind::Eval,
    }
}

/// A stage's work units (agent steps of a training, episodes of a search or an evaluation)
/// and its cost class.
pub fn units(ex: &Experiment, stage: &Stage) -> (f64, String) {
    let evals = |runs: usize| (ex.test_worlds.len() * runs) as f64;
    let class = |arm: usize, network: bool, with_space: bool| {
        let a = &ex.arms[arm];
        let space = with_space.then(|| space_label(a.space));
        cost_class(kind(stage), &planner_name(a.planner), space.as_deref(), network)
    };
    let arm_of = |planner, speed| {
        ex.arms
            .iter()
            .position(|a| a.planner == planner && a.speed == speed)
            .expect("a DDP stage comes from an arm")
    };
    match *stage {
        Stage::Train { arm, .. } => {
            let a = &ex.arms[arm];
            let td3 = &ex.train.td3;
            let class = train_class(
                &planner_name(a.planner),
                Some(&space_label(a.space)),
                td3.batch_size as f64 * td3.updates_per_insert,
            );
            (ex.train.run.steps as f64, class)
        }
        Stage::Search { arm } => {
            let s = &ex.search;
            let rungs = halving(
                s.candidates,
                s.eta,
                s.first_pairs,
                ex.search_worlds.len() * s.runs,
            );
            let mut before = 0;
            let mut episodes = 0;
            for (keep, upto) in rungs {
                episodes += keep * (upto - before);
                before = upto;
            }
            (episodes as f64, class(arm, false, true))
        }
        Stage::EvalDdp { planner, speed } | Stage::EvalVanilla { planner, speed } => {
            (evals(ex.eval.runs), class(arm_of(planner, speed), false, false))
        }
        Stage::EvalConstant { arm } => (evals(ex.eval.runs), class(arm, false, true)),
        Stage::EvalUntrained { arm } | Stage::EvalAdp { arm, .. } => {
            (evals(ex.eval.runs), class(arm, true, true))
        }
        Stage::EvalShuffled { arm, .. } => (
            evals(ex.eval.runs) + ex.pool_worlds.len() as f64,
            class(arm, true, true),
        ),
        Stage::Sweep { arm, who, .. } => (evals(ex.sweep.runs), who_class(ex, stage, arm, who)),
        Stage::Sensing { arm, who, .. } => (evals(ex.sensing.runs), who_class(ex, stage, arm, who)),
    }
}

fn who_class(ex: &Experiment, stage: &Stage, arm: usize, who: SweepWho) -> String {
    let a = &ex.arms[arm];
    let space = space_label(a.space);
    let (network, space) = match who {
        SweepWho::Ddp => (false, None),
        SweepWho::Constant => (false, Some(space.as_str())),
        SweepWho::Adp { .. } => (true, Some(space.as_str())),
    };
    cost_class(kind(stage), &planner_name(a.planner), space, network)
}

/// Core-seconds per unit when the store has measured nothing of a class: measured on a
/// 2-core x86-64 VM (DWA at 1.5 m/s: a 120,000-step training in about 1,120 s; 225 worlds x 20
/// runs of DDP in about 180 s, of a policy choosing DWA's weights about 400 s, of a policy
/// driving the robot itself about 510 s, every run to its time limit). The other planners'
/// episodes cost about 2.5 times DWA's.
fn default_rate(class: &str) -> f64 {
    let mut parts = class.split(':');
    let (kind, planner) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let rest: Vec<&str> = parts.collect();
    let planner_factor = if planner == "dwa" { 1.0 } else { 2.5 };
    let space = rest.last().copied().unwrap_or("-");
    let space_factor = if space == "velocity" {
        2.8
    } else if space.contains("weights") {
        2.2
    } else {
        1.0
    };
    match kind {
        "train" => 0.019 * if planner == "dwa" { 1.0 } else { 1.5 },
        _ => 0.08 * planner_factor * space_factor,
    }
}

/// Measured core-seconds per unit, per cost class.
#[derive(Clone, Debug, Default)]
pub struct Rates {
    /// Class -> (total core-seconds, total units).
    measured: BTreeMap<String, (f64, f64)>,
}

impl Rates {
    /// The rates of `metas` (every finished stage of a store).
    pub fn measured(metas: &[StageMeta]) -> Self {
        let mut measured: BTreeMap<String, (f64, f64)> = BTreeMap::new();
        for m in metas.iter().filter(|m| m.seconds > 0.0) {
            // Only the units its time covers (a resumed training's may be fewer than all).
            let timed = m.timed_units.unwrap_or(m.units).min(m.units);
            if timed <= 0.0 {
                continue;
            }
            let e = measured.entry(class_of(m)).or_default();
            // The CPU time it used where measured (a machine shared with other work inflates
            // wall time, not CPU time), else its wall time on every thread it had.
            e.0 += m.cpu_s.unwrap_or(m.seconds * m.threads.max(1) as f64);
            e.1 += timed;
        }
        Rates { measured }
    }

    /// Core-seconds per unit of `class`, and whether it was measured (else the default).
    pub fn rate(&self, class: &str) -> (f64, bool) {
        match self.measured.get(class) {
            Some(&(s, u)) if u > 0.0 => (s / u, true),
            _ => (default_rate(class), false),
        }
    }

    /// Estimated core-seconds of `stage`.
    pub fn cost(&self, ex: &Experiment, stage: &Stage) -> (f64, bool) {
        let (units, class) = units(ex, stage);
        let (rate, measured) = self.rate(&class);
        (units * rate, measured)
    }
}

/// A one-line progress bar: `[#####.....] 5/10 stages, 1.2 of 2.4 core-h, about 0.9 h left`.
/// `done_est` and `left_est` are the estimated core-seconds of the stages this run computed
/// and of the remaining ones (a stage it skipped is in neither), `elapsed_s` the wall time so
/// far; the time left scales the remaining estimate by what the computed stages took against
/// their estimate, or, before any was computed, divides it over `cores`.
pub fn progress_line(
    done: usize,
    total: usize,
    done_est: f64,
    left_est: f64,
    elapsed_s: f64,
    cores: usize,
) -> String {
    const WIDTH: usize = 20;
    let frac = if done_est + left_est > 0.0 {
        done_est / (done_est + left_est)
    } else {
        done as f64 / total.max(1) as f64
    };
    let filled = ((frac * WIDTH as f64).round() as usize).min(WIDTH);
    let bar: String = "#".repeat(filled) + &".".repeat(WIDTH - filled);
    let wall_left = if done_est > 0.0 && elapsed_s > 0.0 {
        left_est * elapsed_s / done_est
    } else {
        left_est / cores.max(1) as f64
    };
    format!(
        "[{bar}] {done}/{total} stages, {:.1} of {:.1} core-h, about {:.1} h left",
        done_est / 3600.0,
        (done_est + left_est) / 3600.0,
        wall_left / 3600.0
    )
}

/// `--plan`: every stage still to compute with its estimated core-hours, and what the store
/// already holds.
pub(crate) fn print_plan(ex: &Experiment, layout: &Layout, config: &Path, only: &[String], cores: u32) {
    let all: Vec<Stage> = stages(&ex.arms, ex.seeds, &Sweeps::of(ex))
        .into_iter()
        .filter(|s| only.is_empty() || only.iter().any(|k| k == s.kind_name()))
        .collect();
    let rates = Rates::measured(&layout.store.all_meta());
    let mut held: std::collections::BTreeMap<String, usize> = Default::default();
    let mut todo = Vec::new();
    for s in &all {
        if layout.done(s) {
            let by = layout
                .store
                .meta(&layout.recipe(s))
                .map_or_else(|| "an unrecorded run".to_string(), |m| m.experiment);
            *held.entry(by).or_default() += 1;
        } else {
            todo.push(s.clone());
        }
    }
    println!(
        "adp experiment --config {}: {} arm(s) x {} seed(s), {} stage(s); store {}",
        config.display(),
        ex.arms.len(),
        ex.seeds,
        all.len(),
        layout.store.dir.display()
    );
    let in_store = all.len() - todo.len();
    if in_store > 0 {
        let by: Vec<String> = held.iter().map(|(e, n)| format!("{n} by {e}")).collect();
        println!("already in the store: {in_store} stage(s) ({})", by.join(", "));
    }
    if todo.is_empty() {
        println!("nothing left to compute");
        return;
    }
    println!("\nto compute: {} stage(s)", todo.len());
    println!("| stage | units | core-s per unit | est. core-h |");
    println!("|---|---:|---:|---:|");
    let mut total = 0.0;
    let mut defaults = 0;
    for s in &todo {
        let (units, class) = units(ex, s);
        let (rate, measured) = rates.rate(&class);
        defaults += usize::from(!measured);
        total += units * rate;
        println!(
            "| {} | {units:.0} | {rate:.3}{} | {:.2} |",
            s.describe(&ex.arms),
            if measured { "" } else { " (default)" },
            units * rate / 3600.0
        );
    }
    let cores = cores.max(1) as f64;
    println!(
        "\ntotal: {:.1} core-h, about {:.1} h on this machine's {cores:.0} core(s)",
        total / 3600.0,
        total / 3600.0 / cores
    );
    if defaults > 0 {
        println!(
            "{defaults} estimate(s) use a default rate: the store has measured no stage of their \
             class yet (units: agent steps of a training, episodes otherwise)"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Restrict;

    fn meta(class: &str, units: f64, seconds: f64, threads: usize) -> StageMeta {
        StageMeta {
            description: String::new(),
            experiment: "t".into(),
            class: class.into(),
            units,
            seconds,
            threads,
            cpu_s: None,
            timed_units: None,
            finished_unix_s: 0,
            recipe: serde_json::Value::Null,
        }
    }

    #[test]
    fn cpu_time_is_the_cost_where_it_was_measured() {
        let shared = StageMeta {
            cpu_s: Some(100.0),
            ..meta("eval:dwa:schedule:-", 1000.0, 200.0, 2)
        };
        assert_eq!(
            Rates::measured(&[shared]).rate("eval:dwa:schedule:-"),
            (0.1, true)
        );
    }

    /// A training resumed after a run whose time is not known is priced by the steps its
    /// recorded time covers, not by all of them.
    #[test]
    fn a_resumed_training_is_priced_by_the_steps_its_time_covers() {
        let through = StageMeta {
            cpu_s: Some(4800.0),
            ..meta("train:log-mppi:decremental", 120_000.0, 2900.0, 2)
        };
        let resumed = StageMeta {
            cpu_s: Some(1400.0),
            timed_units: Some(35_000.0),
            ..meta("train:log-mppi:decremental", 120_000.0, 900.0, 2)
        };
        let (rate, measured) = Rates::measured(&[through, resumed]).rate("train:log-mppi:decremental");
        // 6,200 core-seconds over 155,000 steps, not over 240,000.
        assert!(measured && (rate - 0.04).abs() < 1e-12, "{rate}");
    }

    #[test]
    fn measured_rates_pool_their_class_and_others_fall_back() {
        let rates = Rates::measured(&[
            meta("eval:dwa:schedule:-", 1000.0, 50.0, 2),
            meta("eval:dwa:schedule:-", 3000.0, 50.0, 2),
        ]);
        // 200 core-seconds over 4,000 episodes.
        assert_eq!(rates.rate("eval:dwa:schedule:-"), (0.05, true));
        let (mppi, measured) = rates.rate("eval:mppi:schedule:-");
        assert!(!measured && mppi > rates.rate("eval:dwa:schedule:-").0);
    }

    /// A training's cost follows its learner's work per agent step: one that replays a
    /// quarter of the default's samples is its own class, even where an older record named
    /// only its planner and space, and batch 512 at a quarter of the updates is the default's.
    #[test]
    fn trainings_are_classed_by_the_samples_their_learner_replays() {
        let training = |batch: usize, rate: f64, cpu_s: f64| StageMeta {
            cpu_s: Some(cpu_s),
            recipe: serde_json::json!({
                "kind": "train",
                "inputs": {"td3": {"batch_size": batch, "updates_per_insert": rate}}
            }),
            ..meta("train:dwa:decremental", 120_000.0, 4000.0, 2)
        };
        let rates = Rates::measured(&[training(128, 1.0, 3000.0), training(128, 0.25, 780.0)]);
        assert_eq!(rates.rate("train:dwa:decremental"), (0.025, true));
        assert_eq!(rates.rate("train:dwa:decremental:replay32"), (0.0065, true));
        let class = |td3: &str| {
            let text = format!(
                "[experiment]\nname = \"u\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n[train.td3]\n{td3}\n"
            );
            let ex = Experiment::parse("u.toml", &text, &Restrict::default()).unwrap();
            units(&ex, &Stage::Train { arm: 0, seed: 0 }).1
        };
        assert_eq!(class(""), "train:dwa:decremental");
        assert_eq!(
            class("updates_per_insert = 0.25"),
            "train:dwa:decremental:replay32"
        );
        assert_eq!(
            class("batch_size = 512\nupdates_per_insert = 0.25"),
            "train:dwa:decremental"
        );
    }

    #[test]
    fn units_count_episodes_and_agent_steps() {
        let text = "[experiment]\nname = \"u\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n\
                    [eval]\nruns = 10\ntrim = 2\n[constant_search]\ncandidates = 9\neta = 3\nfirst_pairs = 25\nruns = 3\n\
                    [train.run]\nsteps = 1000\n";
        let ex = Experiment::parse("u.toml", text, &Restrict::default()).unwrap();
        let n = ex.test_worlds.len() as f64;
        assert_eq!(units(&ex, &Stage::Train { arm: 0, seed: 0 }).0, 1000.0);
        assert_eq!(units(&ex, &Stage::EvalAdp { arm: 0, seed: 0 }).0, n * 10.0);
        assert_eq!(
            units(&ex, &Stage::EvalShuffled { arm: 0, seed: 0 }).0,
            n * 10.0 + ex.pool_worlds.len() as f64
        );
        // 9 candidates on 25 pairs, 3 on 75, 1 on the rest: 9 x 25 + 3 x 50 + 1 x (pairs - 75).
        let pairs = ex.search_worlds.len() * 3;
        let rungs = halving(9, 3, 25, pairs);
        let expect: usize = rungs
            .iter()
            .scan(0, |before, &(keep, upto)| {
                let e = keep * (upto - *before);
                *before = upto;
                Some(e)
            })
            .sum();
        assert_eq!(units(&ex, &Stage::Search { arm: 0 }).0, expect as f64);
        assert!(expect >= 9 * 25);
    }

    #[test]
    fn the_progress_line_scales_what_is_left_by_what_the_finished_stages_took() {
        // Estimated 1 h done and 1 h left; the first hour took half the time on the wall.
        let line = progress_line(5, 10, 3600.0, 3600.0, 1800.0, 2);
        assert!(line.starts_with("[##########..........] 5/10 stages"), "{line}");
        assert!(line.ends_with("about 0.5 h left"), "{line}");
    }
}
