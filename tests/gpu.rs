//! `adp train --device wgpu`: a short run whose learner computes on wgpu checkpoints and
//! exports, and resumes on the CPU as the same run. It needs a Vulkan device (Mesa's lavapipe
//! runs on the CPU); without one, or in a build without the `wgpu` feature, it prints why and
//! skips, unless ADP_REQUIRE_WGPU=1 (`.ci/run` installs lavapipe and sets it).

use std::path::Path;

use learner_service::read_status;

mod common;
use common::{adp, fresh_dir};

/// A short run: small batches, a short warm-up, fast leases.
fn config(dir: &Path) -> std::path::PathBuf {
    let p = dir.join("gpu.toml");
    std::fs::write(
        &p,
        "[td3]\nwarmup_steps = 128\nbatch_size = 32\nrate_tolerance = 64.0\nactor_warmup_updates = 0\n\n\
         [service]\nheartbeat_ms = 200\nlease_ttl_ms = 2000\nstatus_every_s = 0.2\n\n\
         [greedy]\nevery_steps = 0\n",
    )
    .unwrap();
    p
}

#[test]
fn a_run_trains_on_wgpu_and_resumes_on_the_cpu() {
    let dir = fresh_dir("gpu-train");
    let (cfg, run) = (config(&dir), dir.join("run"));
    let out = adp()
        .args([
            "train", "--device", "wgpu", "--steps", "300", "--actors", "2", "--config",
        ])
        .arg(&cfg)
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() && err.contains("[learner] device `wgpu`") {
        assert!(
            std::env::var_os("ADP_REQUIRE_WGPU").is_none_or(|v| v != "1"),
            "ADP_REQUIRE_WGPU=1: {err}"
        );
        eprintln!("skipped: {}", err.lines().last().unwrap_or_default());
        return;
    }
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("device=wgpu"),
        "the learner says where it computes: {err}"
    );
    let first = read_status(&run).unwrap();
    assert!(
        first.finished && first.inserts >= 300 && first.updates > 0,
        "{first:?}"
    );
    assert!(run.join("export/policy.onnx").is_file() && run.join("export/policy.safetensors").is_file());
    let checkpoints = std::fs::read_dir(run.join("checkpoints")).unwrap().count();
    assert!(checkpoints > 0, "no checkpoint");
    // The same run, resumed on the CPU from the wgpu learner's checkpoint.
    let budget = (first.inserts + 200).to_string();
    let out = adp()
        .args([
            "train", "--device", "cpu", "--resume", "--actors", "2", "--steps", &budget, "--config",
        ])
        .arg(&cfg)
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let s = read_status(&run).unwrap();
    assert_eq!(s.run_id, first.run_id);
    assert!(s.resumed_from.is_some(), "{s:?}");
    assert!(
        s.updates > first.updates && s.inserts >= first.inserts + 200,
        "{s:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_unknown_device_is_refused_naming_the_choices() {
    let out = adp().args(["train", "--device", "cuda"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unknown device `cuda` (cpu or wgpu)"), "{err}");
}
