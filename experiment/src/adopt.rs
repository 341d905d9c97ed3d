//! `adp experiment --adopt RUN_DIR...`: a finished `adp train` run becomes one of the
//! experiment's trainings in the store, when what decided it is what the experiment's training
//! would be (the same recipe: its resolved `config.toml` gives the same inputs), so the
//! experiment evaluates it instead of training again.
//!
//! Copied into the store: the export (`export/`), the learning curves (`greedy_eval.jsonl`),
//! `config.toml` and `status.json`; the training state (checkpoints, event files, tokens) is not.
//! The result's record says where it came from; it carries no timing, so it never feeds the
//! plan's rates.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde_json::Value;

use train_config::TrainConfig;

use super::execute::{load_policy, write_trained};
use super::plan::Stage;
use super::recipe::train_inputs;
use super::store::StageMeta;
use super::Ctx;

/// Where two JSON values differ: up to `max` paths (`run.steps: 120000 against 40000`).
pub fn differences(a: &Value, b: &Value, max: usize) -> Vec<String> {
    fn walk(path: &str, a: &Value, b: &Value, out: &mut Vec<String>, max: usize) {
        if out.len() >= max || a == b {
            return;
        }
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => {
                let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
                keys.sort();
                keys.dedup();
                for k in keys {
                    let p = if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    };
                    walk(
                        &p,
                        x.get(k).unwrap_or(&Value::Null),
                        y.get(k).unwrap_or(&Value::Null),
                        out,
                        max,
                    );
                }
            }
            _ => out.push(format!("{path}: {a} against {b}")),
        }
    }
    let mut out = Vec::new();
    walk("", a, b, &mut out, max);
    out
}

/// Adopts each of `dirs`; returns how many were adopted. A run that does not fit is reported
/// with the reason and left alone.
pub(super) fn adopt(ctx: &Ctx<'_>, dirs: &[PathBuf], cores: u32) -> anyhow::Result<usize> {
    let mut adopted = 0;
    for dir in dirs {
        match adopt_one(ctx, dir, cores) {
            Ok(Some(stage)) => {
                adopted += 1;
                tracing::info!("{}: adopted as `{}`", dir.display(), stage.describe(&ctx.ex.arms));
            }
            Ok(None) => {}
            Err(e) => tracing::warn!("{}: not adopted: {e:#}", dir.display()),
        }
    }
    Ok(adopted)
}

/// Adopts `dir` as the training it matches; `None` when the store already holds it.
fn adopt_one(ctx: &Ctx<'_>, dir: &Path, cores: u32) -> anyhow::Result<Option<Stage>> {
    let ex = ctx.ex;
    let cfg = TrainConfig::load(Some(&dir.join("config.toml")))?;
    let inputs = train_inputs(&cfg, cores);
    let trainings: Vec<Stage> = (0..ex.arms.len())
        .flat_map(|arm| (0..ex.seeds).map(move |seed| Stage::Train { arm, seed }))
        .collect();
    let Some(stage) = trainings
        .iter()
        .find(|s| ctx.layout.recipe(s).inputs == inputs)
        .cloned()
    else {
        // The nearest training: the same planner, space and speed cap, and TD3 seed.
        let near = trainings.iter().find(|s| {
            let Stage::Train { arm, seed } = **s else {
                return false;
            };
            let a = &ex.arms[arm];
            (a.planner, a.space) == (cfg.run.planner, cfg.run.action_space)
                && a.speed == cfg.run.max_speed
                && ex.section.first_seed + seed as u64 == cfg.td3.seed
        });
        let why = near.map_or_else(
            || {
                "no training of the experiment has its planner, action space, speed cap and TD3 seed"
                    .to_string()
            },
            |s| {
                format!(
                    "it differs from `{}` in {}",
                    s.describe(&ex.arms),
                    differences(&inputs, &ctx.layout.recipe(s).inputs, 5).join("; ")
                )
            },
        );
        bail!("not one of this experiment's trainings: {why}");
    };
    if ctx.layout.done(&stage) {
        tracing::info!(
            "{}: the store already holds `{}`",
            dir.display(),
            stage.describe(&ex.arms)
        );
        return Ok(None);
    }
    let Stage::Train { arm, seed } = stage else {
        unreachable!("trainings only")
    };
    let a = &ex.arms[arm];
    let policy = load_policy(&dir.join("export"), a.space)?;
    let src = &policy.card.source;
    if src.inserts < cfg.run.steps {
        bail!(
            "its export holds {} of {} agent steps: the run has not finished",
            src.inserts,
            cfg.run.steps
        );
    }
    let to = ctx.layout.run_dir(arm, seed);
    copy_dir(&dir.join("export"), &to.join("export"))?;
    for file in ["greedy_eval.jsonl", "config.toml", "status.json"] {
        let from = dir.join(file);
        if from.is_file() {
            std::fs::copy(&from, to.join(file)).with_context(|| format!("cannot copy {}", from.display()))?;
        }
    }
    let recipe = ctx.layout.recipe(&stage);
    ctx.layout.store.write_meta(
        &recipe,
        &StageMeta {
            description: stage.describe(&ex.arms),
            experiment: format!("adopted from {}", short(dir)),
            class: super::estimate::units(ex, &stage).1,
            units: cfg.run.steps as f64,
            seconds: 0.0,
            threads: 0,
            cpu_s: None,
            timed_units: None,
            finished_unix_s: 0,
            recipe: serde_json::to_value(&recipe).expect("recipes serialize"),
        },
    )?;
    write_trained(ctx, arm, seed, &cfg, &policy, to.join("export"))?;
    Ok(Some(stage))
}

/// The last two components of `dir` (`steps120k/seed-0`): where an adopted run came from,
/// without the machine's absolute path, which a report kept in a repository should not carry.
fn short(dir: &Path) -> String {
    let parts: Vec<String> = dir
        .components()
        .rev()
        .take(2)
        .map(|c| c.as_os_str().to_string_lossy().to_string())
        .collect();
    parts.into_iter().rev().collect::<Vec<_>>().join("/")
}

/// Copies the regular files of `from` into `to` (created).
fn copy_dir(from: &Path, to: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(to).with_context(|| format!("cannot create {}", to.display()))?;
    for e in std::fs::read_dir(from).with_context(|| format!("cannot read {}", from.display()))? {
        let e = e?;
        if e.file_type()?.is_file() {
            std::fs::copy(e.path(), to.join(e.file_name()))
                .with_context(|| format!("cannot copy {}", e.path().display()))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn an_adopted_run_is_named_without_the_machine_path() {
        assert_eq!(
            short(Path::new("/work/runs/steps120k/seed-0")),
            "steps120k/seed-0"
        );
        assert_eq!(short(Path::new("seed-0")), "seed-0");
    }

    #[test]
    fn differences_name_the_paths_that_differ() {
        let a = json!({"run": {"steps": 120000, "actors": 2}, "td3": {"seed": 1}});
        let b = json!({"run": {"steps": 40000, "actors": 2}, "td3": {"seed": 1}, "extra": true});
        assert_eq!(
            differences(&a, &b, 5),
            ["extra: null against true", "run.steps: 120000 against 40000"]
        );
        assert_eq!(differences(&a, &a, 5), Vec::<String>::new());
        assert_eq!(differences(&a, &b, 1).len(), 1);
    }
}
