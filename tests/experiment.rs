//! `adp experiment` end to end on a tiny configuration (2 test worlds, 1 seed, a 200-step
//! training run, 3 runs per world with 1 trimmed from each end): the report, the results and
//! PNG figures exist; a resumed experiment skips every finished stage (the trained arm is not
//! trained again); the learner's greedy evaluations make the learning curves; a changed
//! experiment file or a second start in the same directory is refused; evaluation in two
//! shards, merged, equals the unsharded one. A one-condition sensing sweep (dropout 0, the
//! configuration's own lidar) reproduces the main DDP evaluation run for run.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::SystemTime;

mod common;
use common::{cluster, fresh_dir, run as adp, stderr};

const TINY: &str = r#"
[experiment]
name = "tiny"
planners = ["dwa"]
speeds = [1.5]
train_worlds = ["150,153"]
test_worlds = "0,1"
seeds = 1

[eval]
runs = 3
trim = 1

[constant_search]
worlds = "150,153"
candidates = 3

[shuffle]
worlds = "150"
pool = 64

[sensing_sweep]
dropouts = [0.0]
runs = 3
trim = 1

[stats]
resamples = 200

[train.run]
steps = 200
actors = 1

[train.greedy]
every_steps = 100
worlds = "153"

[train.td3]
actor_hidden = [64, 64]
critic_hidden = [64, 64]
batch_size = 32
warmup_steps = 100
"#;

/// The stage outputs of the experiment in `out`, sorted, each with its modification time:
/// the training markers (`runs/**/trained.json`) and the JSON files of the constant searches
/// and evaluations (`search/`, `eval/`, without the exported untrained policies).
fn stage_outputs(out: &Path) -> Vec<(PathBuf, SystemTime)> {
    fn walk(dir: &Path, keep: &dyn Fn(&Path) -> bool, found: &mut Vec<(PathBuf, SystemTime)>) {
        for path in std::fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
        {
            if path.is_dir() && !path.ends_with("untrained-policy") {
                walk(&path, keep, found);
            } else if path.is_file() && keep(&path) {
                let modified = std::fs::metadata(&path).unwrap().modified().unwrap();
                found.push((path, modified));
            }
        }
    }
    let mut found = Vec::new();
    walk(&out.join("runs"), &|p| p.ends_with("trained.json"), &mut found);
    for dir in ["search", "eval"] {
        walk(
            &out.join(dir),
            &|p| p.extension().is_some_and(|e| e == "json"),
            &mut found,
        );
    }
    found.sort();
    found
}

fn is_png(path: &Path) -> bool {
    std::fs::read(path).is_ok_and(|b| b.starts_with(b"\x89PNG\r\n\x1a\n") && b.len() > 1000)
}

#[test]
fn tiny_experiment_reports_resumes_and_refuses_mixing() {
    let dir = fresh_dir("experiment-tiny");
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let out = dir.join("out");
    let (c, o) = (config.to_str().unwrap(), out.to_str().unwrap());

    let first = adp(&["experiment", "--config", c, "--out", o]);
    assert!(first.status.success(), "{}", stderr(&first));
    // The seven stages (training, constant search; DDP, constant, untrained, ADP and shuffled
    // evaluations) and the three of the sensing sweep (DDP, constant, ADP) each left their
    // output.
    let outputs = stage_outputs(&out);
    assert_eq!(outputs.len(), 10, "{outputs:#?}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in [
        "## Table I",
        "| DDP |",
        "best constant",
        "untrained (DDP init)",
        "state-shuffled",
        "ADP-decremental",
        "## Paired statistics",
        "greedy-evaluation learning curves",
        "## Sensing conditions",
        "| method | 720 beams, noise 0.001 m |",
    ] {
        assert!(report.contains(needle), "report lacks {needle:?}:\n{report}");
    }
    let arm = "dwa-decremental-1.5-150_153";
    for fig in ["learning", "scatter", "clutter", "episode"] {
        let p = out.join("figures").join(format!("{fig}-{arm}.png"));
        assert!(is_png(&p), "{} is not a PNG", p.display());
    }
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(results[0]["comparisons"].as_array().unwrap().len(), 4);
    assert_eq!(results[0]["sensing"].as_array().unwrap().len(), 1);
    // The sensing condition is the configuration's own lidar: DDP's runs are the main ones.
    let read = |file: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join(file)).unwrap()).unwrap()
    };
    let (main, sensing) = (
        read("eval/ddp-dwa-1.5.json"),
        read("eval/sensing-0/ddp-dwa-1.5.json"),
    );
    assert_eq!(main["per_world"], sensing["per_world"]);
    assert_eq!(sensing["lidar"]["dropout"], 0.0);

    // Starting again in the same directory is refused; so is resuming with another file.
    let again = adp(&["experiment", "--config", c, "--out", o]);
    assert!(
        !again.status.success() && stderr(&again).contains("--resume"),
        "{}",
        stderr(&again)
    );
    let changed = dir.join("changed.toml");
    std::fs::write(&changed, TINY.replace("candidates = 3", "candidates = 4")).unwrap();
    let mixed = adp(&[
        "experiment",
        "--config",
        changed.to_str().unwrap(),
        "--out",
        o,
        "--resume",
    ]);
    assert!(
        !mixed.status.success() && stderr(&mixed).contains("differs"),
        "{}",
        stderr(&mixed)
    );

    // A resumed experiment skips every finished stage: nothing is trained or evaluated again.
    let resumed = adp(&["experiment", "--config", c, "--out", o, "--resume"]);
    assert!(resumed.status.success(), "{}", stderr(&resumed));
    assert_eq!(stage_outputs(&out), outputs);

    // Sharded evaluation (as the SLURM job runs it) gives the same results once merged: a
    // copy of the trained experiment evaluates in two shards, then merges and reports.
    let out2 = dir.join("out2");
    copy_tree(&out.join("runs"), &out2.join("runs"));
    copy_tree(&out.join("search"), &out2.join("search"));
    std::fs::copy(out.join("experiment.toml"), out2.join("experiment.toml")).unwrap();
    let o2 = out2.to_str().unwrap();
    for k in ["0/2", "1/2"] {
        let s = adp(&["experiment", "--config", c, "--out", o2, "--shard", k]);
        assert!(s.status.success(), "{}", stderr(&s));
        assert!(!out2.join("report.md").exists());
    }
    let evals = [
        "eval/ddp-dwa-1.5.json".to_string(),
        format!("eval/{arm}/constant.json"),
        format!("eval/{arm}/untrained.json"),
        format!("eval/{arm}/seed-0/adp.json"),
        format!("eval/{arm}/seed-0/shuffled.json"),
        "eval/sensing-0/ddp-dwa-1.5.json".to_string(),
        format!("eval/{arm}/sensing-0/constant.json"),
        format!("eval/{arm}/sensing-0/seed-0.json"),
    ];
    for file in &evals {
        // Each shard wrote its half; nothing is merged before the unsharded run.
        let shard = |k: usize| out2.join(format!("{file}.shard-{k}-of-2"));
        assert!(shard(0).is_file() && shard(1).is_file(), "{file}: shards missing");
        assert!(!out2.join(file).exists(), "{file} exists before the merge");
    }
    let merged = adp(&["experiment", "--config", c, "--out", o2, "--resume"]);
    assert!(merged.status.success(), "{}", stderr(&merged));
    for file in &evals {
        let read = |root: &Path| -> serde_json::Value {
            serde_json::from_str(&std::fs::read_to_string(root.join(file)).unwrap()).unwrap()
        };
        let (a, b) = (read(&out), read(&out2));
        assert_eq!(a["per_world"], b["per_world"], "{file}");
        assert_eq!(a["trace"], b["trace"], "{file}");
    }
    assert!(out2.join("report.md").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Copies the regular files under `from` to `to`.
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let t = e.file_type().unwrap();
        if t.is_dir() {
            copy_tree(&e.path(), &to.join(e.file_name()));
        } else if t.is_file() {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// The job `adp experiment --emit-slurm` writes trains, evaluates in two shards, merges and
/// reports on a real (single-host) cluster. `sbatch --wait` is bounded by the job's time
/// limit.
#[test]
fn emitted_slurm_job_runs_the_experiment() {
    if !cluster() {
        return;
    }
    let dir = fresh_dir("experiment-slurm");
    let config = dir.join("tiny.toml");
    let text = TINY.replace(
        "[stats]",
        "[slurm]\ntasks = 2\ncpus_per_task = 1\ntime = \"00:10:00\"\n\n[stats]",
    );
    std::fs::write(&config, text).unwrap();
    let out = dir.join("out");
    let emitted = adp(&[
        "experiment",
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--emit-slurm",
    ]);
    assert!(emitted.status.success(), "{}", stderr(&emitted));
    let script = dir.join("job.sbatch");
    std::fs::write(&script, &emitted.stdout).unwrap();
    let submitted = Command::new("sbatch")
        .args(["--wait", "--parsable"])
        .arg(&script)
        .current_dir(&dir)
        .output()
        .unwrap();
    let logs: String = std::fs::read_dir(out.join("logs"))
        .map(|d| {
            d.flatten()
                .map(|e| std::fs::read_to_string(e.path()).unwrap_or_default())
                .collect()
        })
        .unwrap_or_default();
    assert!(submitted.status.success(), "{}\n{logs}", stderr(&submitted));
    // Five evaluation stages (DDP, constant, untrained, seed 0, shuffled) and the sensing
    // sweep's three (DDP, constant, seed 0 under its one condition).
    assert_eq!(logs.matches("merged 2 shards").count(), 8, "{logs}");
    assert!(out.join("report.md").exists(), "{logs}");
    std::fs::remove_dir_all(&dir).unwrap();
}
