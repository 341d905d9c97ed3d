//! The stages of an experiment, in the order they run: pure bookkeeping, so that a stage
//! whose result exists is skipped.
//!
//! Every stage writes one result into the store of results, under the key of what decides
//! it ([`super::recipe`], [`super::store`]); a training run's result is its run directory,
//! finished by a marker written after its export exists.
//!
//! Arms that differ only in their observation layout or training worlds share their constant
//! search and best constant (which observe nothing and are searched on one set of worlds):
//! those stages are listed once, for the first such arm ([`control_arm`]); arms that differ
//! only in training worlds share their untrained policy too ([`untrained_arm`]). Their recipes
//! are equal, so they would share one result in the store anyway.

use std::path::Path;

use planner::PlannerKind;

use super::config::{planner_name, speed_label, Arm, Experiment, Start};

/// One unit of work.
#[derive(Clone, Debug, PartialEq)]
pub enum Stage {
    /// Train seed `seed` of arm `arm` (an index into the arms).
    Train {
        /// Arm index.
        arm: usize,
        /// Seed index.
        seed: usize,
    },
    /// Search the best constant action of an arm on the training worlds.
    Search {
        /// Arm index.
        arm: usize,
    },
    /// Evaluate DDP for a planner and speed.
    EvalDdp {
        /// The planner.
        planner: PlannerKind,
        /// The speed cap (m/s).
        speed: f64,
    },
    /// Evaluate the vanilla schedule (the planner's uniform fine grid) for a planner and
    /// speed: the calibration row of the DDP paper.
    EvalVanilla {
        /// The planner.
        planner: PlannerKind,
        /// The speed cap (m/s).
        speed: f64,
    },
    /// Evaluate an arm's best constant action.
    EvalConstant {
        /// Arm index.
        arm: usize,
    },
    /// Evaluate an arm's untrained, DDP-initialized policy.
    EvalUntrained {
        /// Arm index.
        arm: usize,
    },
    /// Evaluate a trained policy.
    EvalAdp {
        /// Arm index.
        arm: usize,
        /// Seed index.
        seed: usize,
    },
    /// Evaluate a trained policy fed other steps' observations.
    EvalShuffled {
        /// Arm index.
        arm: usize,
        /// Seed index.
        seed: usize,
    },
    /// Evaluate a controller of the budget sweep under its compute model.
    Sweep {
        /// Arm index.
        arm: usize,
        /// Index of the sweep point ([`super::config::Experiment::sweep_points`]).
        point: usize,
        /// Which controller.
        who: SweepWho,
    },
    /// Evaluate a controller of the sensing sweep under its lidar condition.
    Sensing {
        /// Arm index.
        arm: usize,
        /// Index of the condition ([`super::config::Experiment::sensing_conditions`]).
        condition: usize,
        /// Which controller.
        who: SweepWho,
    },
}

/// The controllers of the budget and sensing sweeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SweepWho {
    /// The DDP schedule.
    Ddp,
    /// The arm's best constant.
    Constant,
    /// A trained policy.
    Adp {
        /// Seed index.
        seed: usize,
    },
}

/// The budget sweep of an experiment: the arm swept and its number of points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SweepPlan {
    /// Arm index.
    pub arm: usize,
    /// Sweep points.
    pub points: usize,
}

/// The sensing sweep of an experiment: the arms covered and the number of conditions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SensingPlan {
    /// Arm indices, in order.
    pub arms: Vec<usize>,
    /// Sensing conditions.
    pub conditions: usize,
}

/// The evaluations beyond the main protocol: the vanilla row and the sweeps after the main
/// evaluations (each `None` when the experiment has none).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Sweeps {
    /// Whether the vanilla schedule is evaluated per planner and speed (after DDP).
    pub vanilla: bool,
    /// The arms without the state-shuffled control (`[shuffle] speeds`).
    pub unshuffled: Vec<usize>,
    /// The budget sweep.
    pub budget: Option<SweepPlan>,
    /// The sensing sweep.
    pub sensing: Option<SensingPlan>,
}

/// The first arm that differs from arm `arm` at most in its observation layout and
/// training worlds: the one whose constant search and best constant the arm shares ([`Arm::same_controls`]).
pub fn control_arm(arms: &[Arm], arm: usize) -> usize {
    arms.iter()
        .position(|a| a.same_controls(&arms[arm]))
        .expect("an arm shares its controls with itself")
}

/// The first arm that differs from arm `arm` at most in its training worlds: the one whose
/// untrained policy and its evaluation the arm shares ([`Arm::same_untrained`]).
pub fn untrained_arm(arms: &[Arm], arm: usize) -> usize {
    arms.iter()
        .position(|a| a.same_untrained(&arms[arm]))
        .expect("an arm shares its untrained policy with itself")
}

/// Every stage of `arms` x `seeds`, in an order that respects their dependencies: all
/// training first (the longest work, so a job that stops early has its policies; an arm that
/// starts from its best constant has its constant search just before its first training),
/// then the constant searches, then the evaluations. DDP runs once per (planner, speed), shared by the
/// arms that differ only in action space, training worlds or observation layout; the constant
/// search and the best constant once per group of arms that differ only in observation layout
/// and training worlds ([`control_arm`]), the untrained policy once per group of arms that
/// differ only in training worlds ([`untrained_arm`]). The budget sweep, if any, comes next (per point: DDP, the best constant,
/// the seeds), then the sensing sweep (per covered arm and condition: DDP for the first
/// covered arm of its planner and speed, the best constant for the first covered arm of its
/// group, the seeds).
pub fn stages(arms: &[Arm], seeds: usize, sweeps: &Sweeps) -> Vec<Stage> {
    let mut out = Vec::new();
    let owns_controls = |arm: usize| control_arm(arms, arm) == arm;
    for arm in 0..arms.len() {
        // An arm that starts from its best constant needs its search before its training.
        let search = Stage::Search {
            arm: control_arm(arms, arm),
        };
        if arms[arm].start == Start::BestConstant && !out.contains(&search) {
            out.push(search);
        }
        for seed in 0..seeds {
            out.push(Stage::Train { arm, seed });
        }
    }
    for arm in (0..arms.len()).filter(|&a| owns_controls(a)) {
        if !out.contains(&Stage::Search { arm }) {
            out.push(Stage::Search { arm });
        }
    }
    let mut ddp: Vec<(PlannerKind, f64)> = Vec::new();
    for a in arms {
        if !ddp.iter().any(|&(p, v)| p == a.planner && v == a.speed) {
            ddp.push((a.planner, a.speed));
        }
    }
    for (planner, speed) in ddp {
        out.push(Stage::EvalDdp { planner, speed });
        if sweeps.vanilla {
            out.push(Stage::EvalVanilla { planner, speed });
        }
    }
    for arm in 0..arms.len() {
        if owns_controls(arm) {
            out.push(Stage::EvalConstant { arm });
        }
        if untrained_arm(arms, arm) == arm {
            out.push(Stage::EvalUntrained { arm });
        }
        for seed in 0..seeds {
            out.push(Stage::EvalAdp { arm, seed });
            if !sweeps.unshuffled.contains(&arm) {
                out.push(Stage::EvalShuffled { arm, seed });
            }
        }
    }
    if let Some(SweepPlan { arm, points }) = sweeps.budget {
        for point in 0..points {
            let who = [SweepWho::Ddp, SweepWho::Constant]
                .into_iter()
                .chain((0..seeds).map(|seed| SweepWho::Adp { seed }));
            out.extend(who.map(|who| Stage::Sweep { arm, point, who }));
        }
    }
    if let Some(plan) = &sweeps.sensing {
        for (k, &arm) in plan.arms.iter().enumerate() {
            let (a, before) = (&arms[arm], &plan.arms[..k]);
            let ddp = !before
                .iter()
                .any(|&b| arms[b].planner == a.planner && arms[b].speed == a.speed);
            let constant = !before.iter().any(|&b| arms[b].same_controls(a));
            for condition in 0..plan.conditions {
                let who = (ddp.then_some(SweepWho::Ddp).into_iter())
                    .chain(constant.then_some(SweepWho::Constant))
                    .chain((0..seeds).map(|seed| SweepWho::Adp { seed }));
                out.extend(who.map(|who| Stage::Sensing { arm, condition, who }));
            }
        }
    }
    out
}

/// The stages that `done` does not report as finished, in order.
pub fn pending(stages: &[Stage], done: impl Fn(&Stage) -> bool) -> Vec<Stage> {
    stages.iter().filter(|s| !done(s)).cloned().collect()
}

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename, so
/// `path` exists only complete. Creates the parent directory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    use anyhow::Context;
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let tmp = path.with_extension(format!("tmp-{}", std::process::id()));
    std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), path.display()))
}

impl Stage {
    /// The trained policy (arm, seed) a stage evaluates, if any.
    pub fn policy(&self) -> Option<(usize, usize)> {
        match *self {
            Stage::EvalAdp { arm, seed }
            | Stage::EvalShuffled { arm, seed }
            | Stage::Sweep {
                arm,
                who: SweepWho::Adp { seed },
                ..
            }
            | Stage::Sensing {
                arm,
                who: SweepWho::Adp { seed },
                ..
            } => Some((arm, seed)),
            _ => None,
        }
    }

    /// A stage's kind, as `--only` names it.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Stage::Train { .. } => "train",
            Stage::Search { .. } => "search",
            Stage::EvalDdp { .. } => "ddp",
            Stage::EvalVanilla { .. } => "vanilla",
            Stage::EvalConstant { .. } => "constant",
            Stage::EvalUntrained { .. } => "untrained",
            Stage::EvalAdp { .. } => "adp",
            Stage::EvalShuffled { .. } => "shuffled",
            Stage::Sweep { .. } => "sweep",
            Stage::Sensing { .. } => "sensing",
        }
    }

    /// A stage in words.
    pub fn describe(&self, arms: &[Arm]) -> String {
        match *self {
            Stage::Train { arm, seed } => format!("train {} seed {seed}", arms[arm].id()),
            Stage::Search { arm } => format!(
                "search the best constant of {} on the training worlds",
                arms[arm].id()
            ),
            Stage::EvalDdp { planner, speed } => {
                format!(
                    "evaluate DDP ({} at {} m/s)",
                    planner_name(planner),
                    speed_label(speed)
                )
            }
            Stage::EvalVanilla { planner, speed } => format!(
                "evaluate vanilla ({} at {} m/s)",
                planner_name(planner),
                speed_label(speed)
            ),
            Stage::EvalConstant { arm } => format!("evaluate the best constant of {}", arms[arm].id()),
            Stage::EvalUntrained { arm } => format!("evaluate the untrained policy of {}", arms[arm].id()),
            Stage::EvalAdp { arm, seed } => format!("evaluate {} seed {seed}", arms[arm].id()),
            Stage::EvalShuffled { arm, seed } => {
                format!("evaluate the state-shuffled {} seed {seed}", arms[arm].id())
            }
            Stage::Sweep { arm, point, who } => {
                format!("budget sweep point {point} of {}: {who:?}", arms[arm].id())
            }
            Stage::Sensing { arm, condition, who } => {
                format!("sensing condition {condition} of {}: {who:?}", arms[arm].id())
            }
        }
    }

    /// The arm a stage belongs to (a DDP stage to the first arm of its planner and speed).
    pub fn arm(&self, arms: &[Arm]) -> Option<usize> {
        match *self {
            Stage::Train { arm, .. }
            | Stage::Search { arm }
            | Stage::EvalConstant { arm }
            | Stage::EvalUntrained { arm }
            | Stage::EvalAdp { arm, .. }
            | Stage::EvalShuffled { arm, .. }
            | Stage::Sweep { arm, .. }
            | Stage::Sensing { arm, .. } => Some(arm),
            Stage::EvalDdp { planner, speed } | Stage::EvalVanilla { planner, speed } => {
                arms.iter().position(|a| a.planner == planner && a.speed == speed)
            }
        }
    }
}

impl Sweeps {
    /// The budget sweep of `ex`, if it has one.
    pub fn budget(ex: &Experiment) -> Option<SweepPlan> {
        let points = ex.sweep_points().len();
        (points > 0).then_some(SweepPlan {
            arm: ex.sweep.arm,
            points,
        })
    }

    /// The sensing sweep of `ex`, if it has one.
    fn sensing(ex: &Experiment) -> Option<SensingPlan> {
        let conditions = ex.sensing_conditions().len();
        (conditions > 0).then(|| SensingPlan {
            arms: ex.sensing_arms(),
            conditions,
        })
    }

    /// The sweeps of `ex`.
    pub fn of(ex: &Experiment) -> Sweeps {
        let shuffled_speeds = &ex.shuffle.speeds;
        Sweeps {
            vanilla: ex.eval.vanilla,
            unshuffled: (0..ex.arms.len())
                .filter(|&i| {
                    !shuffled_speeds.is_empty()
                        && !shuffled_speeds
                            .iter()
                            .any(|v| (v - ex.arms[i].speed).abs() < 1e-9)
                })
                .collect(),
            budget: Self::budget(ex),
            sensing: Self::sensing(ex),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Restrict;
    use crate::eval_config;
    use crate::store::{Layout, Store};
    use actor::LaserLayout;
    use planner::ActionSpace;

    fn arms() -> Vec<Arm> {
        [
            (PlannerKind::Dwa, ActionSpace::Decremental),
            (PlannerKind::Dwa, ActionSpace::Incremental),
        ]
        .into_iter()
        .map(|(planner, space)| Arm {
            planner,
            space,
            speed: 1.5,
            train_worlds: "train".into(),
            observation: None,
            start: Start::Ddp,
            recipe: None,
        })
        .collect()
    }

    /// An arm that starts from its best constant has its constant search before its
    /// training, once (also when it shares the search with a DDP-started arm listed first),
    /// and an untrained policy of its own; an experiment without one keeps its order.
    #[test]
    fn a_best_constant_start_searches_before_it_trains() {
        let mut arms = arms();
        arms.push(Arm {
            start: Start::BestConstant,
            ..arms[0].clone()
        });
        let s = stages(&arms, 2, &Sweeps::default());
        let at = |x: &Stage| s.iter().position(|y| y == x).unwrap();
        assert_eq!(s.iter().filter(|x| **x == Stage::Search { arm: 0 }).count(), 1);
        assert!(at(&Stage::Search { arm: 0 }) < at(&Stage::Train { arm: 2, seed: 0 }));
        assert!(at(&Stage::Train { arm: 0, seed: 1 }) < at(&Stage::Search { arm: 0 }));
        assert_eq!(control_arm(&arms, 2), 0);
        assert_eq!(untrained_arm(&arms, 2), 2);
        let plain = stages(&arms[..2], 2, &Sweeps::default());
        assert!(matches!(plain[4], Stage::Search { arm: 0 }));
    }

    #[test]
    fn the_budget_sweep_comes_last_with_ddp_the_constant_and_every_seed_per_point() {
        let plain = stages(&arms(), 2, &Sweeps::default());
        let budget = Some(SweepPlan { arm: 1, points: 3 });
        let s = stages(
            &arms(),
            2,
            &Sweeps {
                budget,
                ..Sweeps::default()
            },
        );
        assert_eq!(s[..plain.len()], plain[..]);
        let sweep = &s[plain.len()..];
        assert_eq!(sweep.len(), 3 * (2 + 2));
        assert!(sweep.iter().all(|x| matches!(x, Stage::Sweep { arm: 1, .. })));
    }

    /// Arms that differ only in their training worlds train and evaluate their policies each,
    /// but share DDP, the constant search, the best constant and the untrained policy (it has
    /// seen no world), whose files are the first arm's; an arm with another observation layout
    /// among them shares the controls but has an untrained policy of its own.
    #[test]
    fn training_world_arms_share_their_controls_and_untrained_policy() {
        let mut arms: Vec<Arm> = ["train", "generated:75", "generated"]
            .into_iter()
            .map(|w| Arm {
                train_worlds: w.into(),
                ..arms()[0].clone()
            })
            .collect();
        arms.push(Arm {
            observation: Some(LaserLayout::Sectors(15)),
            ..arms[1].clone()
        });
        let s = stages(&arms, 2, &Sweeps::default());
        let count = |f: &dyn Fn(&Stage) -> bool| s.iter().filter(|x| f(x)).count();
        assert_eq!(count(&|x| matches!(x, Stage::Train { .. })), 8);
        assert_eq!(count(&|x| matches!(x, Stage::EvalAdp { .. })), 8);
        assert_eq!(count(&|x| matches!(x, Stage::EvalShuffled { .. })), 8);
        assert_eq!(count(&|x| matches!(x, Stage::Search { .. })), 1);
        assert_eq!(count(&|x| matches!(x, Stage::EvalConstant { .. })), 1);
        assert_eq!(count(&|x| matches!(x, Stage::EvalDdp { .. })), 1);
        assert_eq!(count(&|x| matches!(x, Stage::EvalUntrained { .. })), 2);
        assert_eq!((untrained_arm(&arms, 2), untrained_arm(&arms, 3)), (0, 3));
        assert_eq!((control_arm(&arms, 2), control_arm(&arms, 3)), (0, 0));
    }

    /// The arms of one space in three observation layouts: the scan (no suffix) and two of
    /// their own, then another space.
    fn layout_arms() -> Vec<Arm> {
        let mut out: Vec<Arm> = [
            None,
            Some(LaserLayout::Sectors(15)),
            Some(LaserLayout::Sectors(50)),
        ]
        .into_iter()
        .map(|observation| Arm {
            observation,
            ..arms()[0].clone()
        })
        .collect();
        out.push(arms()[1].clone());
        out
    }

    /// Arms that differ only in their observation layout train and evaluate their policies
    /// each, but share DDP, the constant search and the best constant, whose files are the
    /// first arm's.
    #[test]
    fn observation_arms_share_their_controls() {
        let arms = layout_arms();
        let s = stages(&arms, 1, &Sweeps::default());
        let count = |f: &dyn Fn(&Stage) -> bool| s.iter().filter(|x| f(x)).count();
        assert_eq!(count(&|x| matches!(x, Stage::Train { .. })), 4);
        assert_eq!(count(&|x| matches!(x, Stage::EvalAdp { .. })), 4);
        assert_eq!(count(&|x| matches!(x, Stage::EvalUntrained { .. })), 4);
        assert_eq!(count(&|x| matches!(x, Stage::Search { .. })), 2);
        assert_eq!(count(&|x| matches!(x, Stage::EvalConstant { .. })), 2);
        assert_eq!(count(&|x| matches!(x, Stage::EvalDdp { .. })), 1);
        assert_eq!((control_arm(&arms, 2), control_arm(&arms, 3)), (0, 3));
    }

    /// The sensing sweep comes after the budget sweep: per covered arm and condition, DDP
    /// once per planner and speed, the best constant once per group of arms sharing it,
    /// then every seed; one file per stage.
    #[test]
    fn the_sensing_sweep_comes_last_in_arm_and_condition_order() {
        let arms = layout_arms();
        let budget = Some(SweepPlan { arm: 0, points: 2 });
        let before = stages(
            &arms,
            2,
            &Sweeps {
                budget,
                ..Sweeps::default()
            },
        );
        let sensing = Some(SensingPlan {
            arms: vec![1, 2, 3],
            conditions: 4,
        });
        let s = stages(
            &arms,
            2,
            &Sweeps {
                budget,
                sensing,
                ..Sweeps::default()
            },
        );
        assert_eq!(s[..before.len()], before[..]);
        let sweep = &s[before.len()..];
        // Arm 1: DDP, constant, 2 seeds; arm 2: 2 seeds (its DDP and constant are arm 1's);
        // arm 3: its own constant and 2 seeds (DDP is arm 1's), for each of 4 conditions.
        assert_eq!(sweep.len(), 4 * (4 + 2 + 3));
        let who = |arm: usize, condition: usize| -> Vec<SweepWho> {
            sweep
                .iter()
                .filter_map(|x| match *x {
                    Stage::Sensing {
                        arm: a,
                        condition: c,
                        who,
                    } if (a, c) == (arm, condition) => Some(who),
                    _ => None,
                })
                .collect()
        };
        let seeds = [SweepWho::Adp { seed: 0 }, SweepWho::Adp { seed: 1 }];
        assert_eq!(
            who(1, 3),
            [&[SweepWho::Ddp, SweepWho::Constant][..], &seeds].concat()
        );
        assert_eq!(who(2, 0), seeds);
        assert_eq!(who(3, 2), [&[SweepWho::Constant][..], &seeds].concat());
        // Arm-major, then condition order.
        assert_eq!(
            sweep[..5],
            [
                Stage::Sensing {
                    arm: 1,
                    condition: 0,
                    who: SweepWho::Ddp
                },
                Stage::Sensing {
                    arm: 1,
                    condition: 0,
                    who: SweepWho::Constant
                },
                Stage::Sensing {
                    arm: 1,
                    condition: 0,
                    who: seeds[0]
                },
                Stage::Sensing {
                    arm: 1,
                    condition: 0,
                    who: seeds[1]
                },
                Stage::Sensing {
                    arm: 1,
                    condition: 1,
                    who: SweepWho::Ddp
                },
            ]
        );
    }

    #[test]
    fn stages_cover_every_arm_and_seed_once_with_ddp_shared() {
        let s = stages(&arms(), 2, &Sweeps::default());
        let count = |f: &dyn Fn(&Stage) -> bool| s.iter().filter(|x| f(x)).count();
        assert_eq!(count(&|x| matches!(x, Stage::Train { .. })), 4);
        assert_eq!(
            count(&|x| matches!(x, Stage::EvalDdp { .. })),
            1,
            "one DDP per planner and speed"
        );
        assert_eq!(count(&|x| matches!(x, Stage::EvalAdp { .. })), 4);
        assert_eq!(s.len(), 4 + 2 + 1 + 2 * (2 + 4));
        // Every training comes before every evaluation of a policy.
        let last_train = s.iter().rposition(|x| matches!(x, Stage::Train { .. })).unwrap();
        let first_adp = s.iter().position(|x| matches!(x, Stage::EvalAdp { .. })).unwrap();
        assert!(last_train < first_adp);
    }

    /// An arm without the state-shuffled control has its policies evaluated, not their
    /// shuffled twins.
    #[test]
    fn unshuffled_arms_skip_the_shuffled_control() {
        let s = stages(
            &arms(),
            2,
            &Sweeps {
                unshuffled: vec![0],
                ..Sweeps::default()
            },
        );
        let shuffled: Vec<usize> = s
            .iter()
            .filter_map(|x| match *x {
                Stage::EvalShuffled { arm, .. } => Some(arm),
                _ => None,
            })
            .collect();
        assert_eq!(shuffled, [1, 1]);
        assert_eq!(s.iter().filter(|x| matches!(x, Stage::EvalAdp { .. })).count(), 4);
    }

    /// With the vanilla row, each planner and speed's vanilla evaluation follows its DDP.
    #[test]
    fn the_vanilla_row_follows_ddp_once_per_planner_and_speed() {
        let plain = stages(&arms(), 1, &Sweeps::default());
        let with = stages(
            &arms(),
            1,
            &Sweeps {
                vanilla: true,
                ..Sweeps::default()
            },
        );
        assert_eq!(with.len(), plain.len() + 1);
        let at = with
            .iter()
            .position(|s| matches!(s, Stage::EvalDdp { .. }))
            .unwrap();
        assert_eq!(
            with[at + 1],
            Stage::EvalVanilla {
                planner: PlannerKind::Dwa,
                speed: 1.5
            }
        );
    }

    /// A resumed experiment skips the finished stages (here: the first arm's whole training
    /// and evaluation) and keeps the rest in order.
    #[test]
    fn resume_skips_finished_stages() {
        let arms = arms();
        let all = stages(&arms, 1, &Sweeps::default());
        let first_arm = |s: &Stage| match *s {
            Stage::Train { arm, .. }
            | Stage::Search { arm }
            | Stage::EvalConstant { arm }
            | Stage::EvalUntrained { arm }
            | Stage::EvalAdp { arm, .. }
            | Stage::EvalShuffled { arm, .. }
            | Stage::Sweep { arm, .. }
            | Stage::Sensing { arm, .. } => arm == 0,
            Stage::EvalDdp { .. } | Stage::EvalVanilla { .. } => true,
        };
        let todo = pending(&all, first_arm);
        assert_eq!(
            todo,
            vec![
                Stage::Train { arm: 1, seed: 0 },
                Stage::Search { arm: 1 },
                Stage::EvalConstant { arm: 1 },
                Stage::EvalUntrained { arm: 1 },
                Stage::EvalAdp { arm: 1, seed: 0 },
                Stage::EvalShuffled { arm: 1, seed: 0 },
            ]
        );
    }

    /// `write_atomic` leaves the complete file and no temporary one.
    #[test]
    fn atomic_writes_leave_no_temporary_file() {
        let dir = std::env::temp_dir().join(format!("adp-plan-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        write_atomic(&dir.join("a/b.json"), b"{}").unwrap();
        assert_eq!(std::fs::read(dir.join("a/b.json")).unwrap(), b"{}");
        assert_eq!(std::fs::read_dir(dir.join("a")).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn shipped(file: &str) -> Experiment {
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .join("configs/experiments")
            .join(file);
        Experiment::load(&path, &Restrict::default()).unwrap()
    }

    /// The shipped experiments keep their arms and stages: table1 (9 arms x 3 seeds, the
    /// budget sweep of arm 0 at 4 points) and rl-dwa (4 arms x 3 seeds, no sweep).
    #[test]
    fn existing_experiments_keep_their_stages_and_ids() {
        let ex = shipped("table1.toml");
        let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
        assert_eq!(
            ids,
            [
                "dwa-decremental-1.0-fit",
                "dwa-decremental-1.5-fit",
                "dwa-decremental-2.0-fit",
                "mppi-decremental-1.0-fit",
                "mppi-decremental-1.5-fit",
                "mppi-decremental-2.0-fit",
                "system-decremental-1.0-fit",
                "system-decremental-1.5-fit",
                "system-decremental-2.0-fit"
            ]
        );
        assert_eq!(Sweeps::of(&ex).sensing, None);
        let all = stages(&ex.arms, ex.seeds, &Sweeps::of(&ex));
        // Training 27, searches 9, DDP 9, per arm constant, untrained, 3 ADP and 3 shuffled
        // (72), the budget sweep 4 x (DDP, constant, 3 seeds).
        assert_eq!(all.len(), 27 + 9 + 9 + 72 + 20);
        assert_eq!(all[27], Stage::Search { arm: 0 });
        assert_eq!(
            all[36],
            Stage::EvalDdp {
                planner: PlannerKind::Dwa,
                speed: 1.0
            }
        );
        assert_eq!(all[45], Stage::EvalConstant { arm: 0 });
        assert_eq!(
            all.last(),
            Some(&Stage::Sweep {
                arm: 0,
                point: 3,
                who: SweepWho::Adp { seed: 2 }
            })
        );
        let ex = shipped("rl-dwa.toml");
        assert_eq!(Sweeps::of(&ex), Sweeps::default());
        let all = stages(&ex.arms, ex.seeds, &Sweeps::of(&ex));
        assert_eq!(all.len(), 12 + 4 + 1 + 4 * 8);
        assert_eq!(
            all.iter().filter(|s| matches!(s, Stage::Search { .. })).count(),
            4
        );
    }

    /// The paper's file: Table I's 12 cells, then Table II's arms (the incremental and
    /// unconstrained spaces on the system and DWA; 4 training-world selections on the system),
    /// then Table I's cells again with this project's recipe (from the best constant): 32 arms
    /// x 3 seeds; the vanilla row per planner and speed; the state-shuffled control in every
    /// Table I cell, of both recipes; 10 runs per world trimmed by 2; the hardest 50 test worlds.
    #[test]
    fn the_paper_experiment_plans_its_tables() {
        let ex = shipped("paper.toml");
        assert_eq!(ex.arms.len(), 32);
        assert_eq!(
            ex.arms[..12]
                .iter()
                .filter(|a| a.space == ActionSpace::Decremental && a.recipe.is_none())
                .count(),
            12
        );
        let ours = &ex.arms[20..];
        assert!(ours.iter().all(|a| a.recipe.as_deref() == Some("project")
            && a.start == Start::BestConstant
            && a.space == ActionSpace::Decremental));
        for (a, b) in ex.arms[..12].iter().zip(ours) {
            assert!(a.same_controls(b) && !a.same_untrained(b), "{}", b.id());
            let (paper, project) = (ex.train_config(a, 0), ex.train_config(b, 0));
            assert_eq!(paper.run.steps, project.run.steps);
            assert!(project.greedy.select && !paper.greedy.select);
        }
        assert_eq!((ex.eval.runs, ex.eval.trim, ex.seeds), (10, 2, 3));
        assert_eq!(ex.hardest_worlds.len(), 50);
        assert!(ex.hardest_worlds.iter().all(|w| ex.test_worlds.contains(w)));
        let all = stages(&ex.arms, ex.seeds, &Sweeps::of(&ex));
        let count = |kind: &str| all.iter().filter(|s| s.kind_name() == kind).count();
        assert_eq!(count("train"), 96);
        assert_eq!((count("ddp"), count("vanilla")), (12, 12));
        // Training-world arms share the system's 1.5 m/s search, and the recipes of a cell
        // share its search; the others search their own.
        assert_eq!(count("search"), 16);
        assert_eq!(count("adp"), 96);
        let shuffled: Vec<&Arm> = all
            .iter()
            .filter_map(|s| match *s {
                Stage::EvalShuffled { arm, .. } => Some(&ex.arms[arm]),
                _ => None,
            })
            .collect();
        // Every Table I cell of both recipes (3 seeds each), and Table II's 1.5 m/s arms.
        assert_eq!(
            shuffled
                .iter()
                .filter(|a| a.space == ActionSpace::Decremental && a.train_worlds == "fit")
                .count(),
            2 * 12 * 3
        );
        assert!(shuffled.iter().all(|a| a.speed == 1.5 || a.train_worlds == "fit"));
    }

    /// The sensing experiment: 4 layouts x 3 seeds trained, one search and one best constant
    /// shared by the layouts, and per condition DDP, the constant and 12 policies.
    #[test]
    fn the_sensing_experiment_plans_its_sweep() {
        let ex = shipped("sensing.toml");
        let all = stages(&ex.arms, ex.seeds, &Sweeps::of(&ex));
        let main = 12 + 1 + 1 + 1 + 4 * (1 + 3 + 3);
        assert_eq!(all.len(), main + 4 * (1 + 1 + 12));
        assert!(all[main..].iter().all(|s| matches!(s, Stage::Sensing { .. })));
    }

    /// The training-worlds experiment: 5 selections x 3 seeds trained; the arms differ only in
    /// training worlds, so one search, one DDP, one best constant and one untrained policy
    /// (the first arm's) serve them all.
    #[test]
    fn the_worlds_experiment_shares_its_controls() {
        let ex = shipped("worlds.toml");
        assert_eq!(ex.arms.len(), 5);
        let all = stages(&ex.arms, ex.seeds, &Sweeps::of(&ex));
        assert_eq!(all.len(), 15 + 1 + 1 + 1 + 1 + 5 * (3 + 3));
        let cfg = eval_config(&ex).unwrap();
        let layout = Layout::new("/e".into(), Store { dir: "/s".into() }, &ex, &cfg, 2);
        for arm in 1..5 {
            for stage in [Stage::EvalConstant { arm }, Stage::EvalUntrained { arm }] {
                let first = match stage {
                    Stage::EvalConstant { .. } => Stage::EvalConstant { arm: 0 },
                    _ => Stage::EvalUntrained { arm: 0 },
                };
                assert_eq!(layout.output(&stage), layout.output(&first), "{stage:?}");
            }
            assert_ne!(layout.run_dir(arm, 0), layout.run_dir(0, 0));
        }
    }
}
