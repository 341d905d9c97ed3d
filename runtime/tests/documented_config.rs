//! `configs/runtime.toml`, the runtime's documented configuration (the guide's configuration
//! reference is generated from it), is a file the runtime reads as it stands, its values are
//! the runtime's defaults, and it names every key the runtime's file format has.

use std::path::{Path, PathBuf};

use adp_runtime::config::read;
use adp_runtime::{FixedSchedule, RuntimeOptions};
use planner::PlannerKind;
use testkit::fresh_dir;

fn documented() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/runtime.toml")
}

/// The keys the runtime's file format has at `table` (top level: `None`), as its parser lists
/// them when refusing an unknown one.
fn known_keys(table: Option<&str>) -> Vec<String> {
    let dir = fresh_dir("runtime-known-keys");
    let probe = match table {
        None => "planner = \"dwa\"\nmax_speed = 1.5\nnot_a_key = 1\n".to_string(),
        Some(t) => format!("planner = \"dwa\"\nmax_speed = 1.5\n[{t}]\nnot_a_key = 1\n"),
    };
    std::fs::write(dir.join("probe.toml"), probe).unwrap();
    let err = read(&dir.join("probe.toml"))
        .expect_err("an unknown key is refused")
        .to_string();
    let _ = std::fs::remove_dir_all(&dir);
    let list = err
        .split_once("expected one of ")
        .unwrap_or_else(|| panic!("the refusal lists the known keys: {err}"))
        .1;
    list.split('`').skip(1).step_by(2).map(str::to_string).collect()
}

#[test]
fn the_documented_configuration_reads_as_the_defaults() {
    let (_, options, policy) = read(&documented()).unwrap();
    assert!(policy.is_none(), "the documented file runs the fixed schedule");
    assert_eq!(options, RuntimeOptions::new(PlannerKind::Dwa, 1.5));
    assert_eq!(options.fixed, FixedSchedule::Ddp);
}

#[test]
fn the_documented_configuration_names_every_key() {
    let text = std::fs::read_to_string(documented()).unwrap();
    // A key is named when a line sets it, shows it commented out (`# key = ...`) or opens
    // its table (`[key]`).
    let named = |key: &str| {
        text.lines().any(|l| {
            let l = l.trim().trim_start_matches('#').trim_start();
            l == format!("[{key}]")
                || l.strip_prefix(key)
                    .is_some_and(|rest| rest.trim_start().starts_with('='))
        })
    };
    for table in [None, Some("lidar")] {
        let keys = known_keys(table);
        assert!(keys.len() >= 4, "{table:?}: {keys:?}");
        let missing: Vec<&String> = keys.iter().filter(|k| !named(k)).collect();
        assert!(
            missing.is_empty(),
            "keys of the runtime's configuration ({}) that configs/runtime.toml does not \
             describe: {missing:?}",
            table.unwrap_or("top level")
        );
    }
}
