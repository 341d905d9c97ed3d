//! `adp experiment` end to end on a tiny configuration (2 test worlds, 1 seed, a 200-step
//! training run, 3 runs per world with 1 trimmed from each end): the report, the results and
//! PNG figures exist; a resumed experiment skips every finished stage (the trained arm is not
//! trained again); the learner's greedy evaluations make the learning curves; a changed
//! experiment file or a second start in the same directory is refused; evaluation in two
//! shards, merged, equals the unsharded one. A one-condition sensing sweep (dropout 0, the
//! configuration's own lidar) reproduces the main DDP evaluation run for run. A second
//! experiment file sharing the arm finds its results in the store of results: it computes
//! nothing for that arm and reports the same numbers for it.

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

/// The stage results in the store `store`, sorted, each with its modification time: the
/// training markers (`train/*/trained.json`) and the JSON results of the constant searches
/// and evaluations (`search/`, `eval/`, without their `.stage.json` records and shards).
fn stage_outputs(store: &Path) -> Vec<(PathBuf, SystemTime)> {
    let mut found = Vec::new();
    let mut add = |p: PathBuf| {
        let t = std::fs::metadata(&p).unwrap().modified().unwrap();
        found.push((p, t));
    };
    if let Ok(d) = std::fs::read_dir(store.join("train")) {
        for e in d.flatten() {
            let marker = e.path().join("trained.json");
            if marker.is_file() {
                add(marker);
            }
        }
    }
    for kind in ["search", "eval"] {
        if let Ok(d) = std::fs::read_dir(store.join(kind)) {
            for e in d.flatten() {
                let name = e.file_name().to_string_lossy().to_string();
                if name.ends_with(".json") && !name.ends_with(".stage.json") {
                    add(e.path());
                }
            }
        }
    }
    found.sort();
    found
}

/// The experiment's stages as its `stages.json` lists them: (stage in words, result in the
/// store, the experiment that computed it).
fn stages(out: &Path) -> Vec<(String, PathBuf, Option<String>)> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stages.json")).unwrap()).unwrap();
    v.as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["stage"].as_str().unwrap().to_string(),
                PathBuf::from(e["result"].as_str().unwrap()),
                e["computed_by"].as_str().map(str::to_string),
            )
        })
        .collect()
}

/// The result of the stage whose words start with `prefix`.
fn result_of(out: &Path, prefix: &str) -> PathBuf {
    stages(out)
        .into_iter()
        .find(|(s, _, _)| s.starts_with(prefix))
        .unwrap_or_else(|| panic!("no stage {prefix:?} in {}", out.display()))
        .1
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn is_png(path: &Path) -> bool {
    std::fs::read(path).is_ok_and(|b| b.starts_with(b"\x89PNG\r\n\x1a\n"))
}

#[test]
fn tiny_experiment_reports_resumes_and_refuses_mixing() {
    let dir = fresh_dir("experiment-tiny");
    let config = dir.join("tiny.toml");
    std::fs::write(&config, TINY).unwrap();
    let (out, store) = (dir.join("out"), dir.join("store"));
    let (c, o, st) = (
        config.to_str().unwrap(),
        out.to_str().unwrap(),
        store.to_str().unwrap(),
    );

    let first = adp(&["experiment", "--config", c, "--out", o, "--store", st]);
    assert!(first.status.success(), "{}", stderr(&first));
    // The seven stages (training, constant search; DDP, constant, untrained, ADP and shuffled
    // evaluations) and the three of the sensing sweep (DDP, constant, ADP) each left their
    // result in the store, and each was computed by this experiment.
    let outputs = stage_outputs(&store);
    assert_eq!(outputs.len(), 10, "{outputs:#?}");
    let listed = stages(&out);
    assert_eq!(listed.len(), 10);
    assert!(
        listed.iter().all(|(_, _, by)| by.as_deref() == Some("tiny")),
        "{listed:#?}"
    );
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
        "10 stage(s), 10 computed by this experiment",
    ] {
        assert!(report.contains(needle), "report lacks {needle:?}:\n{report}");
    }
    let arm = "dwa-decremental-1.5-150_153";
    for fig in ["learning", "scatter", "clutter", "episode"] {
        let p = out.join("figures").join(format!("{fig}-{arm}.png"));
        assert!(is_png(&p), "{} is not a PNG", p.display());
    }
    let results = read_json(&out.join("results.json"));
    assert_eq!(results[0]["comparisons"].as_array().unwrap().len(), 4);
    assert_eq!(results[0]["sensing"].as_array().unwrap().len(), 1);
    // The sensing condition is the configuration's own lidar: DDP's runs are the main ones.
    let main = read_json(&result_of(&out, "evaluate DDP"));
    let sensing = read_json(&result_of(
        &out,
        "sensing condition 0 of dwa-decremental-1.5-150_153: Ddp",
    ));
    assert_eq!(main["per_world"], sensing["per_world"]);
    assert_eq!(sensing["lidar"]["dropout"], 0.0);

    // Starting again in the same directory is refused; so is resuming with another file.
    let again = adp(&["experiment", "--config", c, "--out", o, "--store", st]);
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
        "--store",
        st,
        "--resume",
    ]);
    assert!(
        !mixed.status.success() && stderr(&mixed).contains("differs"),
        "{}",
        stderr(&mixed)
    );

    // A resumed experiment skips every finished stage: nothing is trained or evaluated again.
    let resumed = adp(&["experiment", "--config", c, "--out", o, "--store", st, "--resume"]);
    assert!(resumed.status.success(), "{}", stderr(&resumed));
    assert_eq!(stage_outputs(&store), outputs);

    // Sharded evaluation (as the SLURM job runs it) gives the same results once merged: a
    // second store with the trained policy and the search evaluates in two shards, then
    // merges and reports.
    let (out2, store2) = (dir.join("out2"), dir.join("store2"));
    copy_tree(&store.join("train"), &store2.join("train"));
    copy_tree(&store.join("search"), &store2.join("search"));
    std::fs::create_dir_all(&out2).unwrap();
    std::fs::copy(out.join("experiment.toml"), out2.join("experiment.toml")).unwrap();
    let (o2, st2) = (out2.to_str().unwrap(), store2.to_str().unwrap());
    for k in ["0/2", "1/2"] {
        let s = adp(&[
            "experiment",
            "--config",
            c,
            "--out",
            o2,
            "--store",
            st2,
            "--shard",
            k,
        ]);
        assert!(s.status.success(), "{}", stderr(&s));
        assert!(!out2.join("report.md").exists());
    }
    let evals: Vec<PathBuf> = stages(&out)
        .into_iter()
        .map(|(_, p, _)| p)
        .filter(|p| p.parent().is_some_and(|d| d.ends_with("eval")))
        .map(|p| p.strip_prefix(&store).unwrap().to_path_buf())
        .collect();
    assert_eq!(evals.len(), 8, "{evals:#?}");
    for file in &evals {
        // Each shard wrote its half; nothing is merged before the unsharded run.
        let shard = |k: usize| store2.join(format!("{}.shard-{k}-of-2", file.display()));
        assert!(
            shard(0).is_file() && shard(1).is_file(),
            "{}: shards missing",
            file.display()
        );
        assert!(
            !store2.join(file).exists(),
            "{} exists before the merge",
            file.display()
        );
    }
    let merged = adp(&[
        "experiment",
        "--config",
        c,
        "--out",
        o2,
        "--store",
        st2,
        "--resume",
    ]);
    assert!(merged.status.success(), "{}", stderr(&merged));
    for file in &evals {
        let (a, b) = (read_json(&store.join(file)), read_json(&store2.join(file)));
        assert_eq!(a["per_world"], b["per_world"], "{}", file.display());
        assert_eq!(a["trace"], b["trace"], "{}", file.display());
    }
    assert!(out2.join("report.md").exists());

    // A second experiment file that contains this arm and adds another computes nothing for
    // the shared arm: `--plan` says the store holds its stages, the run leaves their results
    // untouched, and both reports print the same numbers for it.
    let wider = dir.join("wider.toml");
    std::fs::write(
        &wider,
        TINY.replace("name = \"tiny\"", "name = \"wider\"")
            .replace("speeds = [1.5]", "speeds = [1.0, 1.5]")
            .replace(
                "[stats]",
                "[report]\npaper_tables = true\nhardest = \"1\"\n\n[stats]",
            ),
    )
    .unwrap();
    let (w, out3) = (wider.to_str().unwrap(), dir.join("out3"));
    let o3 = out3.to_str().unwrap();
    let plan = adp(&["experiment", "--config", w, "--out", o3, "--store", st, "--plan"]);
    assert!(plan.status.success(), "{}", stderr(&plan));
    let plan_text = String::from_utf8_lossy(&plan.stdout).to_string();
    assert!(
        plan_text.contains("already in the store: 10 stage(s) (10 by tiny)"),
        "{plan_text}"
    );
    assert!(
        plan_text.contains("train dwa-decremental-1.0-150_153 seed 0"),
        "{plan_text}"
    );
    assert!(!plan_text.contains("train dwa-decremental-1.5"), "{plan_text}");
    assert!(plan_text.contains("core-h"), "{plan_text}");
    assert!(!out3.exists(), "--plan created {}", out3.display());
    let second = adp(&["experiment", "--config", w, "--out", o3, "--store", st]);
    assert!(second.status.success(), "{}", stderr(&second));
    let after = stage_outputs(&store);
    for (file, time) in &outputs {
        let now = after.iter().find(|(f, _)| f == file).map(|(_, t)| t);
        assert_eq!(now, Some(time), "{} was computed again", file.display());
    }
    assert_eq!(after.len(), 20, "the new arm's ten results: {after:#?}");
    let report3 = std::fs::read_to_string(out3.join("report.md")).unwrap();
    assert!(
        report3.contains(
            "20 stage(s), 10 computed by this experiment, reused from the store: 10 computed by `tiny`"
        ),
        "{report3}"
    );
    // The wider file leads with the paper's tables and keeps the arms under "arms".
    assert!(report3.contains("### Table I: ADP against DDP"), "{report3}");
    assert!(
        report3.contains("### Table III: the hardest test worlds (`1`)"),
        "{report3}"
    );
    let table1 = std::fs::read_to_string(out3.join("table1.md")).unwrap();
    assert_eq!(
        table1.lines().filter(|l| l.starts_with('|')).count(),
        4,
        "{table1}"
    );
    assert!(
        table1.contains("over the 2 measured cells: above DDP in 0; below the best constant in none."),
        "{table1}"
    );
    let paper = read_json(&out3.join("results.json"));
    assert_eq!(paper["paper"]["table1"].as_array().unwrap().len(), 2);
    assert_eq!(paper["paper"]["table3"][0]["ddp"]["seeds"], 1);
    let arm_results = |out: &Path| -> serde_json::Value {
        let all = read_json(&out.join("results.json"));
        let all = if all.get("arms").is_some() {
            all["arms"].clone()
        } else {
            all
        };
        all.as_array()
            .unwrap()
            .iter()
            .find(|a| a["arm"] == arm)
            .unwrap()
            .clone()
    };
    assert_eq!(arm_results(&out), arm_results(&out3));

    // A finished training run adopted into a fresh store is that store's training: the plan
    // no longer lists it. A run of another configuration is refused, naming what differs.
    let (out4, store4) = (dir.join("out4"), dir.join("store4"));
    let (o4, st4) = (out4.to_str().unwrap(), store4.to_str().unwrap());
    let run = result_of(&out, "train dwa-decremental-1.5-150_153 seed 0");
    let run_dir = run.to_str().unwrap();
    let adopted = adp(&[
        "experiment",
        "--config",
        c,
        "--out",
        o4,
        "--store",
        st4,
        "--adopt",
        run_dir,
    ]);
    assert!(adopted.status.success(), "{}", stderr(&adopted));
    assert!(
        stderr(&adopted).contains("adopted 1 of 1"),
        "{}",
        stderr(&adopted)
    );
    let plan4 = adp(&["experiment", "--config", c, "--out", o4, "--store", st4, "--plan"]);
    let plan4 = String::from_utf8_lossy(&plan4.stdout).to_string();
    assert!(plan4.contains("already in the store: 1 stage(s)"), "{plan4}");
    assert!(!plan4.contains("| train "), "{plan4}");
    let other = dir.join("other.toml");
    std::fs::write(&other, TINY.replace("steps = 200", "steps = 300")).unwrap();
    let refused = adp(&[
        "experiment",
        "--config",
        other.to_str().unwrap(),
        "--out",
        dir.join("out5").to_str().unwrap(),
        "--store",
        st4,
        "--adopt",
        run_dir,
    ]);
    assert!(
        stderr(&refused).contains("run.steps: 200 against 300"),
        "{}",
        stderr(&refused)
    );
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
        "--store",
        dir.join("store").to_str().unwrap(),
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
