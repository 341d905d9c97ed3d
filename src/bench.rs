//! `adp bench`: the command line of `bench::run` (the parts are described in the `adp-bench`
//! crate).

use std::path::PathBuf;

use anyhow::Context;
use bench::load::{LoadOptions, LoadPlane};
use bench::{Options, Part};

/// What `adp bench` runs and how long.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Parts to run (default: all, in this order).
    #[arg(value_enum)]
    pub parts: Vec<Part>,
    /// Timed TD3 updates (learner).
    #[arg(long, default_value_t = 200)]
    pub updates: usize,
    /// The learner's device: cpu or wgpu (learner).
    #[arg(long, default_value_t = learner::LearnerDevice::Cpu)]
    pub device: learner::LearnerDevice,
    /// Batch sizes to time besides the configured one, e.g. 256,1024 (learner).
    #[arg(long, value_delimiter = ',')]
    pub batch: Vec<usize>,
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
    /// Training worlds each planner and schedule runs on (compute, cycle, runtime).
    #[arg(long, default_value_t = 8)]
    pub compute_worlds: usize,
    /// The policy export the runtime part runs (default: the runtime's example export).
    #[arg(long)]
    pub runtime_policy: Option<PathBuf>,
    /// Light actors, each a thread with its own connection, registration, heartbeats, policy
    /// source and step sink (load).
    #[arg(long, default_value_t = 1024)]
    pub load_actors: u32,
    /// The light actors' data plane: grpc (TCP to 127.0.0.1) or shm (shared memory, control
    /// over the learner's Unix socket) (load).
    #[arg(long, value_enum, default_value_t = LoadPlane::Grpc)]
    pub load_plane: LoadPlane,
    /// Seconds of the measured window, after the registrations and a 10 s warm-up (load).
    #[arg(long, default_value_t = 150)]
    pub load_seconds: u64,
    /// Steps per synthetic episode, at most the run's max_agent_steps (load).
    #[arg(long, default_value_t = 100)]
    pub load_episode_steps: u32,
    /// Keep the learner's default connection, registration, policy-stream and shared-memory
    /// caps instead of raising them to the actor count (load).
    #[arg(long)]
    pub load_default_limits: bool,
    /// Also write the figures as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// `adp bench`: runs the parts with this executable as the `adp` of the `train` part.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    let options = Options {
        parts: args.parts,
        updates: args.updates,
        learner_device: args.device,
        batches: args.batch,
        python: args.python,
        records: args.records,
        collect_steps: args.collect_steps,
        train_steps: args.train_steps,
        train_actors: args.train_actors,
        compute_worlds: args.compute_worlds,
        runtime_policy: args.runtime_policy,
        load: LoadOptions {
            actors: args.load_actors,
            plane: args.load_plane,
            seconds: args.load_seconds,
            episode_steps: args.load_episode_steps,
            default_limits: args.load_default_limits,
        },
        json: args.json,
    };
    let adp = std::env::current_exe().context("cannot find this executable")?;
    bench::run(&options, &adp)?;
    Ok(())
}
