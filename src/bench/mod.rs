//! `adp bench`: the figures of DESIGN §8 measured on this machine, each next to its target.
//!
//! - `learner`: one TD3 update at the configured batch (critic-only and with the actor step),
//!   a full replay buffer's memory and sampling time; with `--python`, the same update in
//!   PyTorch (`bench/td3_update.py`, embedded) right after, and the ratio of the two.
//! - `transport` ([`transport`]): step records per second through the shared-memory and the
//!   gRPC data planes.
//! - `collect`: agent steps per second of the actor's episode loop (simulator, planner, policy
//!   inference, exploration; no learner), on one thread and on every core.
//! - `train`: `adp train` end to end (learner + actor processes at one update per step),
//!   agent steps per second once training has started.
//! - `cycle` ([`cycle`], not in the default set): each planner's cycle, measured, next to
//!   the roofline of its counted work on this CPU.
//! - `compute` ([`compute`], not in the default set): the unit costs of planner work on this
//!   machine and the `jackal-onboard-v2` compute platform derived from them.
//!
//! Timing is wall clock in a release build; nothing here is a test.

mod compute;
mod cycle;
mod transport;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::Serialize;

use actor::env::{AdpEnv, End};
use actor::exploration::Exploration;
use actor::policy::{MlpPolicy, Scratch};
use learner::bench::{fitted_policy_weights, replay_full, td3_updates};
use learner_service::read_status;

use crate::config::EvalConfig;
use crate::config::TrainConfig;

/// A part of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
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
}

/// What `adp bench` runs and how long.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Parts to run (default: all, in this order).
    #[arg(value_enum)]
    pub parts: Vec<Part>,
    /// Timed TD3 updates (learner).
    #[arg(long, default_value_t = 200)]
    pub updates: usize,
    /// A Python with torch and numpy: also time the same update in PyTorch and print the
    /// ratio (learner).
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// Step records through shared memory; a quarter of them through gRPC (transport).
    #[arg(long, default_value_t = 400_000)]
    pub records: usize,
    /// Agent steps per collecting thread (collect).
    #[arg(long, default_value_t = 2000)]
    pub collect_steps: u64,
    /// Agent-step budget of the end-to-end `adp train` run (train).
    #[arg(long, default_value_t = 4000)]
    pub train_steps: u64,
    /// Actor processes of the end-to-end run (default: one per core).
    #[arg(long, default_value_t = 0)]
    pub train_actors: u32,
    /// Training worlds each planner and schedule runs on (compute, cycle).
    #[arg(long, default_value_t = 8)]
    pub compute_worlds: usize,
    /// Also write the figures as JSON to this file.
    #[arg(long)]
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
}

/// `adp bench`: runs the parts, printing each figure as it comes and a table at the end.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let parts = if args.parts.is_empty() {
        vec![Part::Learner, Part::Transport, Part::Collect, Part::Train]
    } else {
        args.parts.clone()
    };
    let mut figures = Vec::new();
    for part in parts {
        let got = match part {
            Part::Learner => learner(args),
            Part::Transport => transport(args.records),
            Part::Collect => collect(args.collect_steps),
            Part::Train => train(args.train_steps, args.train_actors),
            Part::Compute => compute::run(args.compute_worlds),
            Part::Cycle => cycle::run(args.compute_worlds),
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
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&figures).expect("figures serialize");
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

fn format_value(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.3}")
    }
}

/// Rayon's thread count (what burn's CPU kernels use), for the PyTorch side.
fn threads() -> usize {
    rayon::current_num_threads()
}

fn learner(args: &BenchArgs) -> anyhow::Result<Vec<Figure>> {
    let cfg = TrainConfig::load(None)?.td3;
    let t = td3_updates(&cfg, args.updates.max(2))?;
    let mut out = vec![
        figure(
            format!(
                "TD3 update, batch {}, mean over {} updates",
                cfg.batch_size, t.updates
            ),
            t.mean_ms,
            "ms",
        ),
        figure("TD3 update, critic-only, median", t.critic_only_median_ms, "ms"),
    ];
    if let Some(ms) = t.with_actor_median_ms {
        out.push(figure("TD3 update, critic + actor + targets, median", ms, "ms"));
    }
    if let Some(python) = &args.python {
        let torch = pytorch_update(python, args.updates.max(2))?;
        out.push(figure(
            format!("PyTorch {} update, mean ({} threads)", torch.torch, torch.threads),
            torch.mean_ms,
            "ms",
        ));
        out.push(figure(
            "PyTorch update, critic-only, median",
            torch.critic_only_median_ms,
            "ms",
        ));
        out.push(figure(
            "PyTorch update, critic + actor + targets, median",
            torch.with_actor_median_ms,
            "ms",
        ));
        out.push(
            figure(
                "speed vs PyTorch (mean time ratio PyTorch / burn)",
                torch.mean_ms / t.mean_ms,
                "x",
            )
            .at_least(1.0),
        );
    }
    let r = replay_full(&cfg);
    out.push(figure(
        format!("replay {}K, slot arrays", r.capacity / 1000),
        r.storage_bytes as f64 / 1e6,
        "MB",
    ));
    if let Some(growth) = r.resident_growth_bytes {
        out.push(figure("replay, resident growth when full", growth as f64 / 1e6, "MB").at_most(800.0));
    }
    out.push(figure(
        format!("replay, sample a batch of {}, median", cfg.batch_size),
        r.sample_median_us,
        "us",
    ));
    out.push(figure(
        format!("replay snapshot ({:.0} MB) write", r.snapshot_bytes as f64 / 1e6),
        r.snapshot_write_s,
        "s",
    ));
    out.push(figure("replay snapshot read", r.snapshot_read_s, "s"));
    Ok(out)
}

/// PyTorch's figures, as `bench/td3_update.py --json` prints them.
#[derive(serde::Deserialize)]
struct TorchTiming {
    torch: String,
    threads: usize,
    mean_ms: f64,
    critic_only_median_ms: f64,
    with_actor_median_ms: f64,
}

fn pytorch_update(python: &Path, updates: usize) -> anyhow::Result<TorchTiming> {
    const SCRIPT: &str = include_str!("../../bench/td3_update.py");
    let dir = tempdir("torch")?;
    let script = dir.join("td3_update.py");
    std::fs::write(&script, SCRIPT).with_context(|| format!("cannot write {}", script.display()))?;
    let out = Command::new(python)
        .arg(&script)
        .args([
            "--json",
            "--threads",
            &threads().to_string(),
            "--updates",
            &updates.to_string(),
        ])
        .output()
        .with_context(|| format!("cannot run {}", python.display()))?;
    let _ = std::fs::remove_dir_all(&dir);
    if !out.status.success() {
        bail!(
            "{} bench/td3_update.py failed ({}): {}",
            python.display(),
            out.status,
            crate::config::one_line(String::from_utf8_lossy(&out.stderr).trim())
        );
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().last().unwrap_or_default();
    serde_json::from_str(line).with_context(|| format!("bench/td3_update.py printed {line:?}"))
}

fn transport(records: usize) -> anyhow::Result<Vec<Figure>> {
    let records = records.max(1000);
    let shm = transport::shm_throughput(records, 4)?;
    let grpc = transport::grpc_throughput(records / 4, 4)?;
    Ok(vec![
        figure(
            "shared-memory step records/s (4 publishers, 730 floats)",
            shm,
            "1/s",
        )
        .at_least(100_000.0),
        figure("gRPC loopback step records/s (4 connections, token)", grpc, "1/s").at_least(20_000.0),
    ])
}

/// The collection loop of one thread: episodes on the training worlds (round robin from
/// `thread`), the DDP-initialized policy with exploration noise 0.2, until `steps` agent steps.
fn collect_steps(
    net: &MlpPolicy,
    cfg: &TrainConfig,
    env: actor::EnvConfig,
    worlds: &[usize],
    thread: usize,
    steps: u64,
) -> anyhow::Result<u64> {
    let eval = EvalConfig::load(None)?;
    let space = cfg.run.action_space;
    let kind = cfg.run.planner;
    let n = actor::observation::obs_dim(env.observation, space, env.observe_tracks);
    let (mut obs, mut action) = (vec![0.0f32; n], vec![0.0f32; space.dim()]);
    let mut scratch = Scratch::default();
    let mut done = 0u64;
    let mut episode = 0usize;
    while done < steps {
        let seed = (thread as u64) << 32 | episode as u64;
        let world = sim::catalog::world(worlds[(thread + episode * 7) % worlds.len()])?;
        let mut env = AdpEnv::new(
            world,
            eval.episode,
            kind.build(&eval.planners(), seed),
            space,
            cfg.run.max_speed,
            env,
            seed,
        )?;
        let mut exploration = Exploration::new(0.2, seed);
        loop {
            env.observation(&mut obs);
            net.act(&obs, &mut action, &mut scratch);
            exploration.perturb(&mut action);
            let out = env.step(&action)?;
            done += 1;
            if out.end != End::Continue || done >= steps {
                break;
            }
        }
        episode += 1;
    }
    Ok(done)
}

fn collect(steps: u64) -> anyhow::Result<Vec<Figure>> {
    let cfg = TrainConfig::load(None)?;
    let space = cfg.run.action_space;
    let worlds = sim::splits::select(&cfg.run.worlds)?;
    let target: Vec<f32> = space.ddp_action().iter().map(|&a| a as f32).collect();
    let (dims, weights) = fitted_policy_weights(&cfg.td3, &target)?;
    let net = MlpPolicy::from_flat(&dims, weights)?;
    let steps = steps.max(10);
    let t = Instant::now();
    let one = collect_steps(&net, &cfg, cfg.env, &worlds, 0, steps)?;
    let single = one as f64 / t.elapsed().as_secs_f64();
    // The same steps without the compute model: what counting and budgeting cost.
    let free = actor::EnvConfig {
        compute: planner::ComputeConfig::FREE,
        ..cfg.env
    };
    let t = Instant::now();
    let one_free = collect_steps(&net, &cfg, free, &worlds, 0, steps)?;
    let single_free = one_free as f64 / t.elapsed().as_secs_f64();
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let t = Instant::now();
    let total: u64 = std::thread::scope(|s| {
        let handles: Vec<_> = (0..cores)
            .map(|i| {
                let (net, cfg, worlds) = (&net, &cfg, &worlds);
                s.spawn(move || collect_steps(net, cfg, cfg.env, worlds, i + 1, steps))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a collecting thread panicked"))
            .sum::<anyhow::Result<u64>>()
    })?;
    let all = total as f64 / t.elapsed().as_secs_f64();
    Ok(vec![
        figure(
            format!(
                "collection, agent steps/s on one core ({} {})",
                cfg.run.planner.name(),
                learner::export::space_name(cfg.run.action_space)
            ),
            single,
            "1/s",
        )
        .at_least(1000.0),
        figure(
            "collection, agent steps/s on one core, compute model free",
            single_free,
            "1/s",
        ),
        figure(
            format!(
                "collection with the compute model ({}) / free (the episodes differ: latency)",
                eval::compute_label(&cfg.env.compute)
            ),
            single / single_free,
            "x",
        ),
        figure(
            format!("collection, agent steps/s on {cores} threads"),
            all,
            "1/s",
        ),
        figure(
            "collection scaling (all threads / (one core x threads))",
            all / (single * cores as f64),
            "x",
        ),
    ])
}

fn tempdir(what: &str) -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("adp-bench-{what}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}

/// Runs `adp train` (this executable) with the embedded config and watches `status.json`:
/// the rate counts from the first sample with updates to the last before the run finished.
fn train(steps: u64, actors: u32) -> anyhow::Result<Vec<Figure>> {
    let dir = tempdir("train")?;
    let run = dir.join("run");
    let log = std::fs::File::create(dir.join("train.log"))?;
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let mut cmd = Command::new(exe);
    cmd.args(["train", "--steps", &steps.to_string(), "--out"])
        .arg(&run);
    if actors > 0 {
        cmd.args(["--actors", &actors.to_string()]);
    }
    let started = Instant::now();
    let mut child = cmd
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .context("cannot start adp train")?;
    let mut first: Option<(Instant, u64, u64)> = None;
    let mut last: Option<(Instant, u64, u64)> = None;
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        std::thread::sleep(Duration::from_millis(500));
        if let Ok(s) = read_status(&run) {
            if s.updates > 0 && !s.finished {
                let now = (Instant::now(), s.inserts, s.updates);
                first.get_or_insert(now);
                last = Some(now);
            }
        }
    };
    let wall = started.elapsed().as_secs_f64();
    if !status.success() {
        bail!(
            "adp train failed ({status}); its log is {}",
            dir.join("train.log").display()
        );
    }
    let s = read_status(&run)?;
    let (Some(a), Some(b)) = (first, last) else {
        bail!("the run finished before a training window could be measured; raise --train-steps");
    };
    let secs = b.0.duration_since(a.0).as_secs_f64().max(1e-9);
    let figures = vec![
        figure(
            "end-to-end agent steps/s while training",
            (b.1 - a.1) as f64 / secs,
            "1/s",
        )
        .at_least(40.0),
        figure(
            "end-to-end updates/s while training",
            (b.2 - a.2) as f64 / secs,
            "1/s",
        ),
        figure(
            format!("end-to-end run of {} agent steps, wall", s.inserts),
            wall,
            "s",
        ),
    ];
    let _ = std::fs::remove_dir_all(&dir);
    Ok(figures)
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

    #[test]
    fn collection_loop_counts_agent_steps_across_episode_ends() {
        let cfg = TrainConfig::load(None).unwrap();
        let space = cfg.run.action_space;
        let dims = [
            actor::observation::obs_dim(cfg.env.observation, space, cfg.env.observe_tracks),
            8,
            space.dim(),
        ];
        let net = MlpPolicy::from_flat(&dims, vec![0.0; actor::policy::param_count(&dims)]).unwrap();
        let worlds = sim::splits::select(&cfg.run.worlds).unwrap();
        // 250 steps cannot fit in one episode (capped at 200 agent steps).
        assert_eq!(collect_steps(&net, &cfg, cfg.env, &worlds, 0, 250).unwrap(), 250);
    }
}
