//! The `adp` command line: the subcommands ([`Cmd`]), each with the clap `Args` its module
//! defines next to its code (option groups several commands share are in `crate::args`), and
//! the dispatch to each command ([`run`]).

use clap::{Parser, Subcommand};

use crate::{
    actor_process, bench, calibrate, eval, experiment, export, render, slurm, stop, tracks, train, worlds,
};

/// `adp`.
#[derive(Parser)]
#[command(
    name = "adp",
    version,
    about = "Adaptive/decremental dynamics planning on BARN"
)]
pub struct Cli {
    /// The command.
    #[command(subcommand)]
    pub cmd: Cmd,
}

/// The subcommands.
#[derive(Subcommand)]
pub enum Cmd {
    /// Evaluate planners x fidelity x speeds on a set of worlds and print the table.
    Eval(eval::EvalArgs),
    /// Run the DDP paper's Table I protocol (300 worlds x 3 runs x 1.0/1.5/2.0 m/s; DWA,
    /// DWA-DDP, MPPI, MPPI-DDP, Log-MPPI, Log-MPPI-DDP, the DDP system) and print our table
    /// beside the paper's with the difference per cell and the calibration checks.
    Calibrate(calibrate::CalibrateArgs),
    /// Draw one episode: world, trajectory, footprints, fidelity-coloured rollouts and moving
    /// obstacles (or, with --frames, a strip of moments of it).
    Render(render::RenderArgs),
    /// Export a checkpoint's policy: policy.onnx, policy.safetensors and policy.json.
    Export(export::ExportArgs),
    /// Train an ADP policy on this machine: a learner and N sandboxed actor processes.
    Train(train::TrainArgs),
    /// The learner half of a distributed run: gRPC control and data planes, shared memory,
    /// replay, TD3, checkpoints.
    Learner(train::LearnerArgs),
    /// The actor half of a distributed run: connects to a learner and runs assignments.
    Actor(actor_process::ActorArgs),
    /// Print the sbatch script of a cluster training job (learner on the first node, actors on
    /// every node, requeue resumes the run).
    Slurm(slurm::SlurmArgs),
    /// Stop a running learner cleanly (final checkpoint) with the operator credential of its
    /// run directory.
    Stop(stop::StopArgs),
    /// Run an experiment (configs/experiments/NAME.toml): train S seeds per arm, evaluate
    /// every policy with the papers' protocol against DDP, the best constant schedule, the
    /// untrained policy and the state-shuffled policy, and write report.md with tables,
    /// paired statistics and figures. Resumable.
    Experiment(experiment::Args),
    /// Where the width of ADP's paired interval comes from (runs within a world, worlds,
    /// seeds) in finished evaluation records, and what other protocols would give.
    Protocol(experiment::ProtocolArgs),
    /// Rewrite format-1 evaluation records (under directories, recursively) in the compact
    /// format 2, once, after checking that their statistics are unchanged.
    CompactRecords(experiment::CompactArgs),
    /// List, inspect, generate or compare worlds and splits.
    Worlds {
        #[command(subcommand)]
        cmd: worlds::WorldsCmd,
    },
    /// Log obstacle tracks and fit PADP's residual corrector of the Kalman forecast (for
    /// `adp eval --prediction kf-res`).
    Tracks {
        #[command(subcommand)]
        cmd: tracks::TracksCmd,
    },
    /// Measure the project's performance figures on this machine (release build) next to
    /// their targets (docs/guide/benchmarks/running.md).
    Bench(bench::BenchArgs),
}

/// Runs the command `cmd`.
pub fn run(cmd: Cmd) -> anyhow::Result<()> {
    match cmd {
        Cmd::Bench(args) => bench::run(args),
        Cmd::Protocol(args) => experiment::protocol_command(&args),
        Cmd::CompactRecords(args) => experiment::compact_command(&args),
        Cmd::Train(a) => train::train_command(a),
        Cmd::Learner(a) => train::learner_command(a),
        Cmd::Actor(args) => actor_process::command(args),
        Cmd::Stop(args) => stop::command(&args),
        Cmd::Slurm(a) => slurm::command(&a),
        Cmd::Eval(args) => eval::command(&args),
        Cmd::Calibrate(args) => calibrate::command(&args),
        Cmd::Render(args) => render::command(&args),
        Cmd::Export(a) => {
            let trained_for = a
                .planner
                .zip(a.max_speed)
                .map(|(planner, max_speed)| learner::export::TrainedFor { planner, max_speed });
            export::run(&a.checkpoint, &a.out, a.action, trained_for)
        }
        Cmd::Experiment(args) => {
            if let Some(report) = experiment::run(&args)? {
                println!("{}", report.display());
            }
            Ok(())
        }
        Cmd::Worlds { cmd } => cmd.run(),
        Cmd::Tracks { cmd } => cmd.run(),
    }
}
