//! The checks of an experiment file: planners and spaces, world splits, the protocol's tables,
//! the command line's restrictions, the arms and the sweeps.

use actor::LaserLayout;
use planner::{ActionSpace, PlannerKind};
use sim::lidar::LidarConfig;
use train_config::TrainConfig;

use super::arm::{planner_name, space_label, speed_label, Arm};
use super::sections::{
    EvalSection, ExperimentSection, SearchSection, SensingSection, ShuffleSection, SlurmJob, StatsSection,
    SweepSection,
};
use super::{ConfigError, Restrict, Result};

/// The planners and action spaces of `[experiment]`, checked with its speeds and seeds.
pub(super) fn planners_and_spaces(
    name: &str,
    ex: &ExperimentSection,
) -> Result<(Vec<PlannerKind>, Vec<ActionSpace>)> {
    let err = |key: &str, what: String| ConfigError::invalid(name, format!("[experiment] {key}: {what}"));
    let planners: Vec<PlannerKind> = ex
        .planners
        .iter()
        .map(|p| {
            p.parse::<PlannerKind>().map_err(|_| {
                err(
                    "planners",
                    format!("unknown planner `{p}` (dwa, mppi, log-mppi, system)"),
                )
            })
        })
        .collect::<Result<_>>()?;
    let spaces: Vec<ActionSpace> = ex
        .action_spaces
        .iter()
        .map(|s| {
            s.parse()
                .map_err(|e: planner::NameError| err("action_spaces", e.to_string()))
        })
        .collect::<Result<_>>()?;
    if planners.is_empty() || spaces.is_empty() || ex.speeds.is_empty() || ex.train_worlds.is_empty() {
        return Err(ConfigError::invalid(
            name,
            "[experiment] planners, action_spaces, speeds and train_worlds must not be empty",
        ));
    }
    // A space that sets a planner's objective gains pairs only with that planner.
    for s in &spaces {
        if let Some(g) = s.gains() {
            if !planners.iter().any(|p| p.name() == g.planner()) {
                return Err(err(
                    "action_spaces",
                    format!(
                        "`{s}` sets the gains of {}, which is not in planners",
                        g.planner()
                    ),
                ));
            }
        }
    }
    for &v in &ex.speeds {
        if !(v.is_finite() && v > 0.0 && v <= 2.0) {
            return Err(err("speeds", format!("{v} must be in (0, 2] m/s")));
        }
    }
    if ex.seeds == 0 {
        return Err(err("seeds", "must be at least 1".into()));
    }
    Ok((planners, spaces))
}

/// The test, constant-search and shuffle-pool world ids, in that order; every selection
/// other than the test worlds (also the training and greedy-evaluation worlds) must select
/// at least one world and no test world.
pub(super) fn world_splits(
    name: &str,
    ex: &ExperimentSection,
    train: &TrainConfig,
    search: &SearchSection,
    shuffle: &ShuffleSection,
) -> Result<(Vec<usize>, Vec<usize>, Vec<usize>)> {
    let select = |section: &str, key: &str, sel: &str| {
        sim::splits::select(sel)
            .map_err(|e| ConfigError::invalid(name, format!("[{section}] {key} = {sel:?}: {e}")))
    };
    let test_worlds = select("experiment", "test_worlds", &ex.test_worlds)?;
    let disjoint = |section: &str, key: &str, sel: &str| -> Result<Vec<usize>> {
        let ids = select(section, key, sel)?;
        if let Some(w) = ids.iter().find(|w| test_worlds.contains(w)) {
            return Err(ConfigError::invalid(
                name,
                format!(
                    "[{section}] {key} = {sel:?} includes test world {w}: the test worlds \
                 ({}) are never used for training or selection",
                    ex.test_worlds
                ),
            ));
        }
        if ids.is_empty() {
            return Err(ConfigError::invalid(
                name,
                format!("[{section}] {key} = {sel:?} selects no world"),
            ));
        }
        Ok(ids)
    };
    for tw in &ex.train_worlds {
        if tw.trim() == sim::splits::FRESH_GENERATED {
            // A new generated world for every assignment: none may be a test world.
            if let Some(w) = test_worlds.iter().find(|&&w| sim::catalog::is_generated(w)) {
                return Err(ConfigError::invalid(
                    name,
                    format!(
                        "[experiment] train_worlds = \"generated\" may deal test world {w} \
                     (the test worlds include generated ones)"
                    ),
                ));
            }
            continue;
        }
        disjoint("experiment", "train_worlds", tw)?;
    }
    if train.greedy.every_steps > 0 {
        disjoint("train.greedy", "worlds", &train.greedy.worlds)?;
    }
    let search_worlds = disjoint("constant_search", "worlds", &search.worlds)?;
    let mut pool_worlds = disjoint("shuffle", "worlds", &shuffle.worlds)?;
    pool_worlds.truncate(shuffle.max_worlds.max(1));
    Ok((test_worlds, search_worlds, pool_worlds))
}

/// Checks `[eval]`, `[constant_search]`, `[slurm]`, `[shuffle]` and `[stats]`, in that order.
pub(super) fn check_tables(
    name: &str,
    ev: &EvalSection,
    cs: &SearchSection,
    sl: &SlurmJob,
    shuffle: &ShuffleSection,
    st: &StatsSection,
) -> Result<()> {
    if ev.runs == 0 || 2 * ev.trim >= ev.runs {
        return Err(ConfigError::invalid(
            name,
            format!(
                "[eval] runs = {} and trim = {}: runs must be at least 1 and trim less than \
             half of runs",
                ev.runs, ev.trim
            ),
        ));
    }
    let jitter = sim::EpisodeConfig {
        start_jitter_m: ev.start_jitter_m,
        start_jitter_yaw_rad: ev.start_jitter_yaw_rad,
        ..sim::EpisodeConfig::default()
    };
    jitter
        .validate()
        .map_err(|e| ConfigError::invalid(name, format!("[eval] {e}")))?;
    if cs.candidates == 0 || cs.runs == 0 || cs.first_pairs == 0 || cs.eta < 2 {
        return Err(ConfigError::invalid(
            name,
            "[constant_search] candidates, runs and first_pairs must be at least 1 and \
             eta at least 2",
        ));
    }
    if sl.nodes == 0 || sl.tasks == 0 || sl.cpus_per_task == 0 || sl.time.is_empty() {
        return Err(ConfigError::invalid(
            name,
            "[slurm] nodes, tasks and cpus_per_task must be at least 1 and time set",
        ));
    }
    if shuffle.pool == 0 {
        return Err(ConfigError::invalid(name, "[shuffle] pool must be at least 1"));
    }
    if !(st.confidence > 0.0 && st.confidence < 1.0) || st.resamples == 0 {
        return Err(ConfigError::invalid(
            name,
            format!(
                "[stats] confidence = {} must be in (0, 1) and resamples = {} at least 1",
                st.confidence, st.resamples
            ),
        ));
    }
    Ok(())
}

/// The seeds per arm after `--seeds`, once every restriction is checked to be a subset of
/// what the file declares.
pub(super) fn restricted_seeds(
    name: &str,
    restrict: &Restrict,
    planners: &[PlannerKind],
    spaces: &[ActionSpace],
    ex: &ExperimentSection,
) -> Result<usize> {
    // Restrictions: each a subset of what the file declares.
    let keep = |flag: &str, listed: bool, value: String| -> Result<()> {
        if listed {
            Ok(())
        } else {
            Err(ConfigError::Restriction(format!(
                "{flag} {value}: not in the experiment's {name}"
            )))
        }
    };
    for p in &restrict.planners {
        keep("--planners", planners.contains(p), planner_name(*p))?;
    }
    for s in &restrict.spaces {
        keep("--spaces", spaces.contains(s), space_label(*s))?;
    }
    for v in &restrict.speeds {
        keep(
            "--speeds",
            ex.speeds.iter().any(|x| (x - v).abs() < 1e-9),
            speed_label(*v),
        )?;
    }
    let seeds = match restrict.seeds {
        Some(0) => return Err(ConfigError::Restriction("--seeds must be at least 1".into())),
        Some(s) if s > ex.seeds => {
            return Err(ConfigError::Restriction(format!(
                "--seeds {s}: the experiment declares {} seeds",
                ex.seeds
            )))
        }
        Some(s) => s,
        None => ex.seeds,
    };
    Ok(seeds)
}

/// The arms, planner-major: every kept planner, action space (a gains space only with its
/// planner), speed, training-world selection and observation layout (`observations`, as
/// [`observation_layouts`] gives them).
pub(super) fn restricted_arms(
    restrict: &Restrict,
    planners: &[PlannerKind],
    spaces: &[ActionSpace],
    ex: &ExperimentSection,
    observations: &[Option<LaserLayout>],
    recipe: Option<&str>,
) -> Vec<Arm> {
    let mut arms = Vec::new();
    for &planner in planners
        .iter()
        .filter(|p| restrict.planners.is_empty() || restrict.planners.contains(p))
    {
        for &space in spaces.iter().filter(|s| {
            (restrict.spaces.is_empty() || restrict.spaces.contains(s))
                && s.gains().is_none_or(|g| g.planner() == planner.name())
        }) {
            for &speed in ex.speeds.iter().filter(|v| {
                restrict.speeds.is_empty() || restrict.speeds.iter().any(|x| (x - *v).abs() < 1e-9)
            }) {
                for tw in &ex.train_worlds {
                    for &observation in observations {
                        arms.push(Arm {
                            planner,
                            space,
                            speed,
                            train_worlds: tw.clone(),
                            observation,
                            start: ex.start,
                            recipe: recipe.map(str::to_string),
                        });
                    }
                }
            }
        }
    }
    arms
}

/// The observation layouts of `[experiment] observations` in file order, `None` for the one
/// of `[train.env] observation` (`base`); absent: that one alone.
pub(super) fn observation_layouts(
    name: &str,
    ex: &ExperimentSection,
    base: LaserLayout,
) -> Result<Vec<Option<LaserLayout>>> {
    let Some(listed) = &ex.observations else {
        return Ok(vec![None]);
    };
    if listed.is_empty() {
        return Err(ConfigError::invalid(
            name,
            "[experiment] observations must not be empty (leave it out for [train.env] observation)",
        ));
    }
    let mut layouts: Vec<LaserLayout> = Vec::new();
    for text in listed {
        let layout: LaserLayout = text
            .parse()
            .map_err(|e| ConfigError::invalid(name, format!("[experiment] observations: {e}")))?;
        if layouts.contains(&layout) {
            return Err(ConfigError::invalid(
                name,
                format!("[experiment] observations: `{text}` is listed twice"),
            ));
        }
        layouts.push(layout);
    }
    Ok(layouts.into_iter().map(|l| (l != base).then_some(l)).collect())
}

/// Checks `[sensing_sweep]` against the experiment's `arm_count` arms: every value a lidar
/// can take, no value twice, its runs and trim, and its arms.
pub(super) fn check_sensing(name: &str, s: &SensingSection, arm_count: usize) -> Result<()> {
    let err = |key: &str, what: String| ConfigError::invalid(name, format!("[sensing_sweep] {key}{what}"));
    let check = |key: &str, value: String, lidar: LidarConfig| {
        lidar.validate().map_err(|e| err(key, format!(" = {value}: {e}")))
    };
    for &beams in &s.beams {
        check(
            "beams",
            beams.to_string(),
            LidarConfig {
                beams,
                ..LidarConfig::default()
            },
        )?;
    }
    for &noise_fraction in &s.noise_fractions {
        let lidar = LidarConfig {
            noise_fraction,
            noise_sigma: 0.0,
            ..LidarConfig::default()
        };
        check("noise_fractions", noise_fraction.to_string(), lidar)?;
    }
    for &dropout in &s.dropouts {
        check(
            "dropouts",
            dropout.to_string(),
            LidarConfig {
                dropout,
                ..LidarConfig::default()
            },
        )?;
    }
    let twice = |values: Vec<String>| {
        let first = values.iter().enumerate().find(|(i, v)| values[..*i].contains(v));
        first.map(|(_, v)| v.clone())
    };
    for (key, values) in [
        ("beams", s.beams.iter().map(ToString::to_string).collect()),
        (
            "noise_fractions",
            s.noise_fractions.iter().map(ToString::to_string).collect(),
        ),
        ("dropouts", s.dropouts.iter().map(ToString::to_string).collect()),
        ("arms", s.arms.iter().map(ToString::to_string).collect()),
    ] {
        if let Some(v) = twice(values) {
            return Err(err(key, format!(": {v} is listed twice")));
        }
    }
    if s.runs == 0 || 2 * s.trim >= s.runs {
        return Err(err(
            "runs",
            format!(
                " = {} and trim = {}: runs must be at least 1 and trim less than half of runs",
                s.runs, s.trim
            ),
        ));
    }
    if let Some(a) = s.arms.iter().find(|&&a| a >= arm_count) {
        return Err(err(
            "arms",
            format!(": arm {a}, but the experiment has {arm_count} arm(s) (indices from 0)"),
        ));
    }
    Ok(())
}

/// Checks `[compute_sweep]` against the experiment's `arm_count` arms.
pub(super) fn check_sweep(name: &str, sweep: &SweepSection, arm_count: usize) -> Result<()> {
    if !sweep.budget_scales.is_empty() || sweep.free {
        if sweep.arm >= arm_count {
            return Err(ConfigError::invalid(
                name,
                format!(
                    "[compute_sweep] arm = {} but the experiment has {} arm(s)",
                    sweep.arm, arm_count
                ),
            ));
        }
        if sweep.runs == 0
            || 2 * sweep.trim >= sweep.runs
            || sweep.budget_scales.iter().any(|k| !(k.is_finite() && *k > 0.0))
        {
            return Err(ConfigError::invalid(
                name,
                format!(
                    "[compute_sweep] runs = {} and trim = {}: runs must be at least 1, trim \
                 less than half of runs, and every budget scale finite and > 0",
                    sweep.runs, sweep.trim
                ),
            ));
        }
    }
    Ok(())
}
