//! The C example builds against `include/adp_runtime.h` and `libadp_runtime_c.so` with the
//! system's C compiler and drives a BARN world to the goal; its outcome is the one the Rust
//! API gives for the same world and seeds.

use std::path::{Path, PathBuf};
use std::process::Command;

use adp_runtime::{sim_robot, Navigator};
use sim::episode::{Episode, Status};

fn config() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../runtime/examples/runtime.toml")
}

/// The directory of this test binary, where cargo also puts the crate's `cdylib`.
fn deps_dir() -> PathBuf {
    std::env::current_exe().unwrap().parent().unwrap().to_path_buf()
}

/// The line the C example prints for `world` and `seed`, computed with the Rust API.
fn rust_line(world: usize, seed: u64) -> String {
    let mut nav = Navigator::from_file(&config()).unwrap();
    let w = &sim::catalog::barn_worlds()[world];
    let mut ep = Episode::new(w, *nav.episode(), seed);
    let (mut cycles, mut planned, mut agent_steps) = (0u64, 0u64, 0u64);
    loop {
        let out = nav.cycle(&sim_robot::observe(&ep)).unwrap();
        cycles += 1;
        planned += u64::from(out.planned);
        agent_steps += u64::from(out.agent_step);
        if sim_robot::apply(&mut ep, out.command, out.planned, out.compute_s) != Status::Running {
            break;
        }
    }
    let r = ep.result();
    let how = match r.status {
        Status::Succeeded => "succeeded",
        Status::Collided => "collided",
        _ => "timed out",
    };
    format!(
        "world {world}: {how} in {:.2} s, score {:.3}; {cycles} cycles, {planned} planned, \
         {agent_steps} agent steps, 0 refused",
        r.time_s, r.score
    )
}

#[test]
fn the_c_example_drives_a_world_as_the_rust_api_does() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let deps = deps_dir();
    assert!(
        deps.join("libadp_runtime_c.so").exists(),
        "{} has no libadp_runtime_c.so: cargo builds the cdylib with the tests",
        deps.display()
    );
    let exe = deps.join(format!("drive_world-{}", std::process::id()));
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let built = Command::new(&cc)
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(crate_dir.join("include"))
        .arg(crate_dir.join("examples/drive_world.c"))
        .arg("-L")
        .arg(&deps)
        .arg("-ladp_runtime_c")
        .arg(format!("-Wl,-rpath,{}", deps.display()))
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap_or_else(|e| panic!("running the C compiler `{cc}` (set CC to choose one): {e}"));
    assert!(
        built.status.success(),
        "the C example does not build:\n{}",
        String::from_utf8_lossy(&built.stderr)
    );
    for (world, seed) in [(3usize, 5u64), (120, 1)] {
        let run = Command::new(&exe)
            .arg(config())
            .arg(world.to_string())
            .arg(seed.to_string())
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&run.stdout);
        assert_eq!(stdout.trim_end(), rust_line(world, seed), "world {world}");
        assert_eq!(
            run.status.success(),
            stdout.contains("succeeded"),
            "exit status {:?} for {stdout}",
            run.status
        );
    }
    let missing = Command::new(&exe)
        .arg("/nonexistent/runtime.toml")
        .output()
        .unwrap();
    assert_eq!(missing.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(
        stderr.starts_with("navigator: /nonexistent/runtime.toml: cannot read"),
        "{stderr}"
    );
    let _ = std::fs::remove_file(&exe);
}
