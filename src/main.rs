//! `adp`: train and ship adaptive-dynamics navigation planners on BARN.

mod actor_process;
mod args;
mod bench;
mod calibrate;
mod cli;
mod config;
mod eval;
mod experiment;
mod export;
#[cfg(test)]
mod reference;
mod render;
mod slurm;
mod stop;
mod tracks;
mod train;
mod worlds;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    keep_freed_memory();
    init_tracing();
    let cli = cli::Cli::parse();
    match cli::run(cli.cmd) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", config::error_line(&e));
            ExitCode::FAILURE
        }
    }
}

/// Crates whose debug events (every HTTP/2 frame) would drown the project's own: logged at
/// `info` unless `RUST_LOG` names them (e.g. `RUST_LOG=debug,h2=debug`).
const QUIET_UNLESS_NAMED: [&str; 5] = ["h2", "hyper", "hyper_util", "tower", "tonic"];

/// Installs the log subscriber: the `tracing` events of every crate at the levels `RUST_LOG`
/// selects (`info` when unset; e.g. `RUST_LOG=debug`, `RUST_LOG=actor=debug,info`, or
/// `RUST_LOG='info,[actor{rank=2}]=debug'` for one actor's session), one line per event on stderr
/// with the fields of the spans it happened in (an actor's `rank` and `actor_id`).
///
/// Each event is formatted into a buffer and written with one `write` to the unbuffered
/// stderr, so the lines of the learner and of its actor processes (the same binary, run as
/// `adp actor`), which share one stderr pipe under `adp train`, never interleave.
fn init_tracing() {
    use std::io::IsTerminal;
    use tracing_subscriber::filter::{EnvFilter, LevelFilter};
    let spec = std::env::var("RUST_LOG").unwrap_or_default();
    let mut filter = EnvFilter::builder()
        .with_default_directive(LevelFilter::INFO.into())
        .parse_lossy(&spec);
    // The HTTP/2 stack logs every frame at debug: it stays at info unless `RUST_LOG` names it.
    for target in QUIET_UNLESS_NAMED {
        if !spec.contains(target) {
            filter = filter.add_directive(format!("{target}=info").parse().expect("a valid directive"));
        }
    }
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
}

/// Tells glibc's allocator to keep freed memory for reuse. A TD3 update allocates and frees
/// several megabytes of tensors (activations, gradients, weight copies of up to 1.5 MB); with
/// glibc's defaults part of that goes back to the kernel after every update (blocks above the
/// mmap threshold, and heap tops above the trim threshold), so the next update page-faults it
/// in again: about 1000 faults per update measured with `perf stat -e page-faults` on
/// `adp bench learner`. Blocks up to 32 MiB now come from the heap, and a heap keeps up to
/// 256 MiB of free space at its top.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only sets allocator parameters; it is called before any other thread
    // exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 256 << 20);
    }
}
