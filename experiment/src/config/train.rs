//! The training configuration of an experiment: `[train]` and the groups' recipes laid over
//! the embedded `configs/local.toml` less the main job's recipe.

use serde::Deserialize;

use eval::config::one_line;
use train_config::TrainConfig;

use super::sections::ExperimentSection;
use super::{ConfigError, Restrict, Result};

/// The embedded training defaults that `[train]` is laid over ([`train_base`]).
const LOCAL_TOML: &str = include_str!("../../../configs/local.toml");

/// The keys of `configs/local.toml` that make the main job's recipe (`adp train` with no
/// `--config`), as `(table, key)`. They do not reach experiments: an experiment takes the
/// code's default of each unless its `[train]` sets it, so changing the main job changes no
/// stored stage.
pub const MAIN_JOB_KEYS: [(&str, &str); 7] = [
    ("run", "steps"),
    ("run", "planner"),
    ("td3", "updates_per_insert"),
    ("service", "init_action"),
    ("greedy", "every_steps"),
    ("greedy", "runs"),
    ("greedy", "select"),
];

/// The table `[train]` is laid over: the embedded `configs/local.toml` less
/// [`MAIN_JOB_KEYS`].
pub fn train_base() -> toml::Table {
    let mut base: toml::Table = toml::from_str(LOCAL_TOML).expect("the embedded local.toml parses");
    for (table, key) in MAIN_JOB_KEYS {
        if let Some(toml::Value::Table(t)) = base.get_mut(table) {
            t.remove(key);
        }
    }
    base
}

/// Deep merge: `over`'s values replace `base`'s, tables merge key by key.
pub(super) fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// `[train]` laid over [`train_base`] and checked, with `--steps` applied; unknown keys of
/// `[train]` are named as written.
pub(super) fn parse_train(name: &str, table: toml::Table, restrict: &Restrict) -> Result<TrainConfig> {
    parse_recipe(name, "[train]", &[table], restrict)
}

/// `layers` laid in order over [`train_base`] and checked, with `--steps` applied; `what`
/// names the last layer in errors (`[train]`, or a group's `train`).
pub(super) fn parse_recipe(
    name: &str,
    what: &str,
    layers: &[toml::Table],
    restrict: &Restrict,
) -> Result<TrainConfig> {
    let mut base = train_base();
    for table in layers {
        // Unknown keys are named before the merge (whose text has other lines).
        TrainConfig::deserialize(table.clone())
            .map_err(|e| ConfigError::invalid(name, format!("{what}: {}", one_line(&e.to_string()))))?;
        merge(&mut base, table.clone());
    }
    let mut train = TrainConfig::parse(
        &format!("{name}: {what}"),
        &toml::to_string(&base).expect("a TOML table serializes"),
    )
    .map_err(|e| ConfigError::Train(one_line(&e.to_string())))?;
    if let Some(steps) = restrict.steps {
        train.run.steps = steps;
    }
    Ok(train)
}

/// The groups' recipes (a group's `train` over `[train]`), by name: a name is lower-case
/// letters, digits and `-`, a `train` table needs one, and groups that share a name share
/// their table.
pub(super) fn group_recipes(
    name: &str,
    ex: &ExperimentSection,
    train: &toml::Table,
    restrict: &Restrict,
) -> Result<Vec<(String, TrainConfig)>> {
    let mut recipes: Vec<(String, &toml::Table, TrainConfig)> = Vec::new();
    for (i, g) in ex.groups.iter().enumerate() {
        let label = format!("[[experiment.groups]] {} ({:?})", i + 1, g.name);
        let err = |what: String| ConfigError::invalid(name, format!("{label}: {what}"));
        let (recipe, table) = match (&g.recipe, &g.train) {
            (None, None) => continue,
            (None, Some(_)) => return Err(err("`train` needs a `recipe` name for its arms".into())),
            (Some(r), None) => {
                return Err(err(format!(
                    "recipe {r:?} has no `train` table (the experiment's own recipe has no name)"
                )))
            }
            (Some(r), Some(t)) => (r, t),
        };
        if recipe.is_empty()
            || !recipe
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-')
        {
            return Err(err(format!(
                "recipe {recipe:?}: a name is lower-case letters, digits and `-`"
            )));
        }
        match recipes.iter().find(|(r, _, _)| r == recipe) {
            Some((_, t, _)) if *t != table => {
                return Err(err(format!(
                    "recipe {recipe:?} is declared twice with different `train` tables"
                )))
            }
            Some(_) => {}
            None => {
                let cfg = parse_recipe(
                    name,
                    &format!("{label} train"),
                    &[train.clone(), table.clone()],
                    restrict,
                )?;
                recipes.push((recipe.clone(), table, cfg));
            }
        }
    }
    Ok(recipes.into_iter().map(|(r, _, c)| (r, c)).collect())
}
