//! `adp`: train and ship adaptive-dynamics navigation planners on BARN.

mod actor_sandbox;
mod bench;
mod calibrate;
mod cli;
mod config;
mod eval;
mod experiment;
mod export;
mod greedy;
mod policy;
mod render;
mod slurm;
mod stop;
mod train;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    keep_freed_memory();
    let cli = cli::Cli::parse();
    match cli::run(cli.cmd) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", config::error_line(&e));
            ExitCode::FAILURE
        }
    }
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
