//! `runtime-capi/install.sh` installs the library (stripped, under its SONAME), the header
//! and the pkg-config file; the C example builds against the installed files with the
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

/// The output of `program args`, which must succeed.
fn output_of(program: &str, args: &[&str]) -> String {
    let out = Command::new(program)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("running {program}: {e}"));
    assert!(
        out.status.success(),
        "{program} {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_c_example_drives_a_world_as_the_rust_api_does() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let deps = deps_dir();
    let built_lib = deps.join("libadp_runtime_c.so");
    assert!(
        built_lib.exists(),
        "{} has no libadp_runtime_c.so: cargo builds the cdylib with the tests",
        deps.display()
    );
    // Installed as the guide says: runtime-capi/install.sh into a prefix of its own.
    let prefix = std::env::temp_dir().join(format!("adp-capi-install-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&prefix);
    let installed = Command::new(crate_dir.join("install.sh"))
        .arg("--prefix")
        .arg(&prefix)
        .arg("--lib")
        .arg(&built_lib)
        .output()
        .unwrap();
    assert!(
        installed.status.success(),
        "install.sh: {}",
        String::from_utf8_lossy(&installed.stderr)
    );
    let lib_dir = prefix.join("lib");
    let version = env!("CARGO_PKG_VERSION");
    let real = lib_dir.join(format!("libadp_runtime.so.{version}"));
    for (link, target) in [
        ("libadp_runtime.so", "libadp_runtime.so.0"),
        ("libadp_runtime.so.0", real.file_name().unwrap().to_str().unwrap()),
    ] {
        assert_eq!(
            std::fs::read_link(lib_dir.join(link)).unwrap(),
            Path::new(target),
            "{link}"
        );
    }
    assert_eq!(
        std::fs::read(prefix.join("include/adp_runtime.h")).unwrap(),
        std::fs::read(crate_dir.join("include/adp_runtime.h")).unwrap()
    );
    // Its SONAME, no run path, and stripped (no symbol table beyond the dynamic one).
    let real_path = real.to_str().unwrap();
    let dynamic = output_of("readelf", &["-d", real_path]);
    assert!(
        dynamic.contains("Library soname: [libadp_runtime.so.0]"),
        "{dynamic}"
    );
    assert!(
        !dynamic.contains("RPATH") && !dynamic.contains("RUNPATH"),
        "{dynamic}"
    );
    let sections = output_of("readelf", &["-S", "-W", real_path]);
    assert!(
        !sections.contains(".symtab") && !sections.contains(".debug_"),
        "{sections}"
    );
    let pc = std::fs::read_to_string(lib_dir.join("pkgconfig/adp_runtime.pc")).unwrap();
    assert!(
        pc.starts_with(&format!("prefix={}\n", prefix.display()))
            && pc.contains(&format!("Version: {version}\n"))
            && pc.contains("Libs: -L${libdir} -ladp_runtime\n")
            && pc.contains("Cflags: -I${includedir}\n"),
        "{pc}"
    );
    if let Ok(flags) = Command::new("pkg-config")
        .args(["--cflags", "--libs", "adp_runtime"])
        .env("PKG_CONFIG_PATH", lib_dir.join("pkgconfig"))
        .output()
    {
        assert_eq!(
            String::from_utf8_lossy(&flags.stdout).trim(),
            format!("-I{0}/include -L{0}/lib -ladp_runtime", prefix.display())
        );
    }
    let exe = deps.join(format!("drive_world-{}", std::process::id()));
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let built = Command::new(&cc)
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(prefix.join("include"))
        .arg(crate_dir.join("examples/drive_world.c"))
        .arg("-L")
        .arg(&lib_dir)
        .arg("-ladp_runtime")
        .arg(format!("-Wl,-rpath,{}", lib_dir.display()))
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap_or_else(|e| panic!("running the C compiler `{cc}` (set CC to choose one): {e}"));
    assert!(
        built.status.success(),
        "the C example does not build:\n{}",
        String::from_utf8_lossy(&built.stderr)
    );
    // The program records the SONAME, so it finds the library after an upgrade.
    let needed = output_of("readelf", &["-d", exe.to_str().unwrap()]);
    assert!(
        needed.contains("Shared library: [libadp_runtime.so.0]"),
        "{needed}"
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
    let _ = std::fs::remove_dir_all(&prefix);
}
