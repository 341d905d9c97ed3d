#![warn(missing_docs)]
//! The project's benchmarks, in one crate: the figures of DESIGN §8 measured on this machine,
//! each next to its target (what `adp bench` runs, [`run`]), the PyTorch reference of the TD3
//! update (`bench/td3_update.py`), and the criterion benches of the simulator and the planners
//! (`bench/benches/`, `cargo bench -p adp-bench`).
//!
//! The parts of [`run`] ([`Part`]):
//!
//! - `learner` ([`td3`]): one TD3 update at the configured batch (critic-only and with the
//!   actor step) and at other batches, on the CPU or wgpu: updates per second, achieved
//!   GFLOP/s and, on the CPU, the share of the machine's peak; a full replay buffer's memory
//!   and sampling time; with a Python, the same update in PyTorch ([`pytorch`]) right after,
//!   and the ratio of the two.
//! - `transport` ([`transport`]): step records per second through the shared-memory and the
//!   gRPC data planes.
//! - `collect` ([`collect`]): agent steps per second of the actor's episode loop (simulator,
//!   planner, policy inference, exploration; no learner), on one thread and on every core.
//! - `train` ([`train`]): `adp train` end to end (learner + actor processes at one update per
//!   step), agent steps per second once training has started.
//! - `cycle` ([`cycle`], not in the default set): each planner's cycle, measured, next to the
//!   roofline of its counted work on this CPU.
//! - `runtime` ([`runtime`], not in the default set): the robot runtime's control cycle,
//!   p50 / p99 / max wall time per planner with DDP and with a policy, against the compute
//!   model's budget; the policy's inference share.
//! - `compute` ([`compute`], not in the default set): the unit costs of planner work on this
//!   machine and the `jackal-onboard-v2` compute platform derived from them.
//! - `load` ([`load`], not in the default set): many light actors (synthetic steps) against
//!   one `adp learner` for minutes, over gRPC or shared memory: steps stored per second,
//!   acknowledgement latency, the learner's memory, registrations per second, nothing lost.
//!
//! Timing is wall clock in a release build; nothing here is a test.

pub mod collect;
pub mod compute;
pub mod cycle;
pub mod load;
pub mod pytorch;
pub mod runtime;
pub mod td3;
pub mod train;
pub mod transport;

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

/// A part of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Part {
    /// TD3 update and replay buffer.
    Learner,
    /// Shared-memory and gRPC step planes.
    Transport,
    /// The actor's episode loop without a learner.
    Collect,
    /// `adp train` end to end.
    Train,
    /// The compute model's unit costs (fit) and platform (not run by default).
    Compute,
    /// Planner cycles against their roofline (not run by default).
    Cycle,
    /// The robot runtime's control cycle against the compute budget (not run by default).
    Runtime,
    /// Many light actors against one learner (not run by default).
    Load,
}

impl Part {
    /// The parts [`run`] runs when none is named, in this order.
    pub const DEFAULT: [Part; 4] = [Part::Learner, Part::Transport, Part::Collect, Part::Train];
}

/// What [`run`] runs and how long (the options of `adp bench`).
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// Parts to run (empty: [`Part::DEFAULT`]), in this order.
    pub parts: Vec<Part>,
    /// Timed TD3 updates (learner).
    pub updates: usize,
    /// The learner's device (learner).
    pub learner_device: learner::LearnerDevice,
    /// Batch sizes timed besides the configured one (learner).
    pub batches: Vec<usize>,
    /// A Python with torch and numpy: also time the same update in PyTorch and the ratio
    /// (learner).
    pub python: Option<PathBuf>,
    /// Step records through shared memory; a quarter of them through gRPC (transport).
    pub records: usize,
    /// Agent steps per collecting thread (collect).
    pub collect_steps: u64,
    /// Agent-step budget of the end-to-end `adp train` run (train).
    pub train_steps: u64,
    /// Actor processes of the end-to-end run (0: one per core).
    pub train_actors: u32,
    /// Training worlds each planner and schedule runs on (compute, cycle, runtime).
    pub compute_worlds: usize,
    /// The policy export the runtime part runs (its example export when `None`).
    pub runtime_policy: Option<PathBuf>,
    /// What the load part runs (load).
    pub load: load::LoadOptions,
    /// Also write the figures as JSON to this file.
    pub json: Option<PathBuf>,
}

/// One measured figure.
#[derive(Debug, Serialize)]
pub struct Figure {
    /// What was measured.
    pub what: String,
    /// The value.
    pub value: f64,
    /// Its unit.
    pub unit: &'static str,
    /// DESIGN §8's target, as text (empty when there is none).
    pub target: String,
    /// Whether the target is met (`None` without a target).
    pub met: Option<bool>,
}

fn figure(what: impl Into<String>, value: f64, unit: &'static str) -> Figure {
    Figure {
        what: what.into(),
        value,
        unit,
        target: String::new(),
        met: None,
    }
}

impl Figure {
    /// Sets a lower bound as the target.
    fn at_least(mut self, bound: f64) -> Self {
        self.target = format!(">= {bound}");
        self.met = Some(self.value >= bound);
        self
    }

    /// Sets an upper bound as the target.
    fn at_most(mut self, bound: f64) -> Self {
        self.target = format!("<= {bound}");
        self.met = Some(self.value <= bound);
        self
    }

    /// Sets an exact value as the target.
    fn exactly(mut self, value: f64) -> Self {
        self.target = format!("= {value}");
        self.met = Some(self.value == value);
        self
    }
}

/// `adp bench`: runs the parts of `options`, printing each figure to stderr as it comes and a
/// table of them to stdout at the end (and the JSON file `options.json` names), and returns
/// them. `adp` is the `adp` executable the `train` part starts as `adp train` and the `load`
/// part as `adp learner`.
pub fn run(options: &Options, adp: &Path) -> anyhow::Result<Vec<Figure>> {
    let parts = if options.parts.is_empty() {
        Part::DEFAULT.to_vec()
    } else {
        options.parts.clone()
    };
    let mut figures = Vec::new();
    for part in parts {
        let got = match part {
            Part::Learner => td3::run(
                options.updates,
                options.python.as_deref(),
                options.learner_device,
                &options.batches,
            ),
            Part::Transport => transport::run(options.records),
            Part::Collect => collect::run(options.collect_steps),
            Part::Train => train::run(adp, options.train_steps, options.train_actors),
            Part::Compute => compute::run(options.compute_worlds),
            Part::Cycle => cycle::run(options.compute_worlds),
            Part::Load => load::run(adp, &options.load),
            Part::Runtime => runtime::run(
                options.compute_worlds,
                options
                    .runtime_policy
                    .as_deref()
                    .unwrap_or(Path::new(runtime::EXAMPLE_POLICY)),
            ),
        }
        .with_context(|| format!("bench {part:?}"))?;
        for f in &got {
            eprintln!("{}: {:.3} {}", f.what, f.value, f.unit);
        }
        figures.extend(got);
    }
    println!("| figure | measured | target | met |\n|---|---|---|---|");
    for f in &figures {
        println!(
            "| {} | {} {} | {} | {} |",
            f.what,
            format_value(f.value),
            f.unit,
            f.target,
            match f.met {
                Some(true) => "yes",
                Some(false) => "no",
                None => "",
            }
        );
    }
    if let Some(path) = &options.json {
        let text = serde_json::to_string_pretty(&figures).expect("figures serialize");
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(figures)
}

fn format_value(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.3}")
    }
}

/// A fresh, empty directory for `what` under the system temp dir.
fn tempdir(what: &str) -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("adp-bench-{what}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_compare_in_the_right_direction() {
        assert_eq!(figure("a", 5.0, "x").at_least(4.0).met, Some(true));
        assert_eq!(figure("a", 3.0, "x").at_least(4.0).met, Some(false));
        assert_eq!(figure("a", 5.0, "x").at_most(4.0).met, Some(false));
        assert_eq!(figure("a", 4.0, "x").at_most(4.0).met, Some(true));
        assert_eq!(figure("a", 4.0, "x").met, None);
    }
}
