//! The one validation layer of both data planes.
//!
//! Every step record, whether it came through gRPC or shared memory, passes
//! [`Validator::check_run`], the learner's [`Admission`] (actor registered, lease valid) and
//! [`Validator::check_step`] (shapes match the run's spaces, values finite, laser and action in
//! range, a coherent episode end) before anything of it reaches the replay buffer. A refused
//! record is counted by reason in [`RefusalCounts`] and logged by the caller with the
//! [`Refusal`]'s message.

use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};

use thiserror::Error;

use crate::floats::RaggedBytes;
use crate::pb;

/// Largest magnitude accepted for a value without a natural range: the reward and the
/// observation values after the laser (previous action, speeds, goal bearings and distances).
/// Real values stay below a few hundred; this bound only stops garbage (1e30, denormal-free
/// overflow bait) from entering the buffer.
pub const MAX_ABS_VALUE: f32 = 1.0e6;

/// Largest magnitude accepted for an episode's return (a sum of at most a few thousand
/// rewards, each within [`MAX_ABS_VALUE`]).
pub const MAX_ABS_RETURN: f64 = 1.0e9;

/// Largest BARN-clock time (s) an episode report may carry (episodes time out at 100 s).
pub const MAX_EPISODE_TIME_S: f64 = 1.0e6;

/// The shapes of a run's observations and actions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Spaces {
    /// Observation length.
    pub obs_dim: usize,
    /// Action length.
    pub act_dim: usize,
    /// How many leading observation values are laser ranges in [-1, 1].
    pub laser_dim: usize,
}

/// One agent step, borrowed from whichever plane carried it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepView<'a> {
    /// The episode (from the actor's assignment).
    pub episode_id: u64,
    /// Position of the step in its episode, from 0.
    pub step_index: u32,
    /// The policy version that chose the action.
    pub policy_version: u64,
    /// `s_t`.
    pub obs: &'a [f32],
    /// `a_t`, normalized.
    pub action: &'a [f32],
    /// `r_t`.
    pub reward: f32,
    /// A true end of the episode (collision, success).
    pub terminal: bool,
    /// A time-limit end; `final_obs` then holds `s_{t+1}`.
    pub truncated: bool,
    /// `s_{t+1}` for a truncated step, empty otherwise.
    pub final_obs: &'a [f32],
}

/// Why a message was refused. The message names the field, index or identifier at fault.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Refusal {
    /// No or a wrong secret token.
    #[error("unauthenticated: {0}")]
    Unauthenticated(String),
    /// The message belongs to another run.
    #[error("wrong run: message for run `{got}`, this learner serves `{expected}`")]
    WrongRun {
        /// The run of this learner.
        expected: String,
        /// The run named by the message.
        got: String,
    },
    /// The message was made for an earlier learner process of this run (register again).
    #[error("stale incarnation {got} (the learner restarted; current incarnation is {current})")]
    StaleIncarnation {
        /// The current incarnation.
        current: u64,
        /// The incarnation named by the message.
        got: u64,
    },
    /// The actor id is not registered (or was retired).
    #[error("actor {0}: {1}")]
    UnknownActor(u64, String),
    /// The lease is unknown, expired, finished or another actor's.
    #[error("lease {0}: {1}")]
    Lease(u64, String),
    /// The episode id or step index does not fit the lease or the episode so far.
    #[error("episode {0}: {1}")]
    Episode(u64, String),
    /// A vector has the wrong length.
    #[error("field `{field}` has {got} values, expected {expected}")]
    Shape {
        /// The field.
        field: &'static str,
        /// Its length.
        got: usize,
        /// The run's length.
        expected: usize,
    },
    /// A value is NaN or infinite.
    #[error("field `{field}`[{index}] is not finite ({value})")]
    NotFinite {
        /// The field.
        field: &'static str,
        /// The first bad index.
        index: usize,
        /// The value.
        value: f32,
    },
    /// A value is outside its range.
    #[error("field `{field}`[{index}] = {value} is outside [-1, 1]")]
    OutOfRange {
        /// The field.
        field: &'static str,
        /// The first bad index.
        index: usize,
        /// The value.
        value: f32,
    },
    /// A value of unbounded range (reward, a non-laser observation) beyond
    /// [`MAX_ABS_VALUE`]: no simulator produces it, and it would swamp every gradient.
    #[error("field `{field}`[{index}] = {value} exceeds the magnitude bound {MAX_ABS_VALUE:e}")]
    Magnitude {
        /// The field.
        field: &'static str,
        /// The first bad index.
        index: usize,
        /// The value.
        value: f32,
    },
    /// A policy version no learner of this run has published yet.
    #[error("field `policy_version` = {got} is newer than the newest published policy version {newest}")]
    FutureVersion {
        /// The version named by the message.
        got: u64,
        /// The newest version published.
        newest: u64,
    },
    /// A number of an episode report that is not finite or outside its range.
    #[error("episode report field `{field}` = {value} is {expected}")]
    Report {
        /// The field.
        field: &'static str,
        /// The value as sent.
        value: f64,
        /// What it should be.
        expected: &'static str,
    },
    /// A free-text field of a registration that is too long or not printable.
    #[error("field `{field}`: {why}")]
    Name {
        /// The field.
        field: &'static str,
        /// What is wrong.
        why: String,
    },
    /// `terminal` and `truncated` together, or `final_obs` without `truncated`.
    #[error("incoherent episode end: {0}")]
    BadEnd(&'static str),
    /// A bytes field that is not a whole number of f32.
    #[error("{0}")]
    Malformed(#[from] RaggedBytes),
}

/// The counting category of a [`Refusal`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(usize)]
pub enum RefusalKind {
    /// [`Refusal::Unauthenticated`].
    Unauthenticated,
    /// [`Refusal::WrongRun`] and [`Refusal::StaleIncarnation`].
    Run,
    /// [`Refusal::UnknownActor`].
    Actor,
    /// [`Refusal::Lease`].
    Lease,
    /// [`Refusal::Episode`].
    Episode,
    /// [`Refusal::Shape`] and [`Refusal::Malformed`].
    Shape,
    /// [`Refusal::NotFinite`].
    NotFinite,
    /// [`Refusal::OutOfRange`] and [`Refusal::BadEnd`].
    Range,
}

impl RefusalKind {
    /// Every kind, in counter order.
    pub const ALL: [RefusalKind; 8] = [
        Self::Unauthenticated,
        Self::Run,
        Self::Actor,
        Self::Lease,
        Self::Episode,
        Self::Shape,
        Self::NotFinite,
        Self::Range,
    ];

    /// A stable snake-case name (status files, TensorBoard tags).
    pub fn name(self) -> &'static str {
        match self {
            Self::Unauthenticated => "unauthenticated",
            Self::Run => "wrong_run",
            Self::Actor => "unknown_actor",
            Self::Lease => "invalid_lease",
            Self::Episode => "bad_episode",
            Self::Shape => "bad_shape",
            Self::NotFinite => "not_finite",
            Self::Range => "out_of_range",
        }
    }
}

impl fmt::Display for RefusalKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl Refusal {
    /// The counting category.
    pub fn kind(&self) -> RefusalKind {
        match self {
            Self::Unauthenticated(_) => RefusalKind::Unauthenticated,
            Self::WrongRun { .. } | Self::StaleIncarnation { .. } => RefusalKind::Run,
            Self::UnknownActor(..) => RefusalKind::Actor,
            Self::Lease(..) => RefusalKind::Lease,
            Self::Episode(..) => RefusalKind::Episode,
            Self::Shape { .. } | Self::Malformed(_) | Self::Name { .. } => RefusalKind::Shape,
            Self::NotFinite { .. } => RefusalKind::NotFinite,
            Self::Report { value, .. } if !value.is_finite() => RefusalKind::NotFinite,
            Self::OutOfRange { .. }
            | Self::Magnitude { .. }
            | Self::FutureVersion { .. }
            | Self::Report { .. }
            | Self::BadEnd(_) => RefusalKind::Range,
        }
    }
}

/// Refused records per [`RefusalKind`]. Lock-free; share it by reference or `Arc` between the
/// planes' threads.
#[derive(Debug, Default)]
pub struct RefusalCounts {
    counts: [AtomicU64; RefusalKind::ALL.len()],
}

impl RefusalCounts {
    /// Counts `n` records refused for `why`.
    pub fn record(&self, why: &Refusal, n: u64) {
        self.counts[why.kind() as usize].fetch_add(n, Ordering::Relaxed);
    }

    /// The count of one kind.
    pub fn get(&self, kind: RefusalKind) -> u64 {
        self.counts[kind as usize].load(Ordering::Relaxed)
    }

    /// All records refused.
    pub fn total(&self) -> u64 {
        RefusalKind::ALL.iter().map(|k| self.get(*k)).sum()
    }

    /// Adds `n` to the kind named `name` (a [`RefusalKind::name`]), e.g. counts restored from a
    /// checkpoint. Returns whether the name is a kind.
    pub fn add_named(&self, name: &str, n: u64) -> bool {
        match RefusalKind::ALL.iter().find(|k| k.name() == name) {
            Some(k) => {
                self.counts[*k as usize].fetch_add(n, Ordering::Relaxed);
                true
            }
            None => false,
        }
    }

    /// The count of every kind by name.
    pub fn by_name(&self) -> std::collections::BTreeMap<String, u64> {
        RefusalKind::ALL
            .iter()
            .map(|k| (k.name().to_owned(), self.get(*k)))
            .collect()
    }

    /// `(name, count)` of every kind.
    pub fn snapshot(&self) -> Vec<(&'static str, u64)> {
        RefusalKind::ALL
            .iter()
            .map(|k| (k.name(), self.get(*k)))
            .collect()
    }
}

/// The learner's registry seen by the validation layer: whether an actor and its lease may
/// deliver data now. Implementations are called from the planes' threads concurrently.
pub trait Admission: Send + Sync {
    /// `Ok` when `actor_id` is registered and `lease_id` is its valid lease; the
    /// [`Refusal::UnknownActor`] or [`Refusal::Lease`] otherwise.
    fn admit(&self, actor_id: u64, lease_id: u64) -> Result<(), Refusal>;
}

/// The run identity and spaces every record is checked against. Plain data (`Send + Sync`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Validator {
    /// The run id.
    pub run_id: String,
    /// The current learner incarnation.
    pub incarnation: u64,
    /// The run's spaces.
    pub spaces: Spaces,
}

impl Validator {
    /// Checks that a message names this run and the current incarnation.
    pub fn check_run(&self, run_id: &str, incarnation: u64) -> Result<(), Refusal> {
        if run_id != self.run_id {
            return Err(Refusal::WrongRun {
                expected: self.run_id.clone(),
                got: run_id.to_owned(),
            });
        }
        if incarnation != self.incarnation {
            return Err(Refusal::StaleIncarnation {
                current: self.incarnation,
                got: incarnation,
            });
        }
        Ok(())
    }

    /// Checks one step's shapes, values and end flags against the run's spaces.
    pub fn check_step(&self, step: &StepView<'_>) -> Result<(), Refusal> {
        let s = &self.spaces;
        check_obs("obs", step.obs, s)?;
        check_len("action", step.action.len(), s.act_dim)?;
        check_finite("action", step.action)?;
        check_unit("action", step.action)?;
        check_finite("reward", &[step.reward])?;
        check_magnitude("reward", &[step.reward])?;
        match (step.terminal, step.truncated) {
            (true, true) => return Err(Refusal::BadEnd("both `terminal` and `truncated` are set")),
            (_, true) => check_obs("final_obs", step.final_obs, s)?,
            (_, false) if !step.final_obs.is_empty() => {
                return Err(Refusal::BadEnd(
                    "`final_obs` given for a step that is not truncated",
                ))
            }
            _ => {}
        }
        Ok(())
    }
}

fn check_len(field: &'static str, got: usize, expected: usize) -> Result<(), Refusal> {
    if got == expected {
        Ok(())
    } else {
        Err(Refusal::Shape { field, got, expected })
    }
}

fn check_finite(field: &'static str, values: &[f32]) -> Result<(), Refusal> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(index) => Err(Refusal::NotFinite {
            field,
            index,
            value: values[index],
        }),
    }
}

fn check_unit(field: &'static str, values: &[f32]) -> Result<(), Refusal> {
    match values.iter().position(|v| !(-1.0..=1.0).contains(v)) {
        None => Ok(()),
        Some(index) => Err(Refusal::OutOfRange {
            field,
            index,
            value: values[index],
        }),
    }
}

fn check_magnitude(field: &'static str, values: &[f32]) -> Result<(), Refusal> {
    match values.iter().position(|v| v.abs() > MAX_ABS_VALUE) {
        None => Ok(()),
        Some(index) => Err(Refusal::Magnitude {
            field,
            index,
            value: values[index],
        }),
    }
}

fn check_obs(field: &'static str, obs: &[f32], s: &Spaces) -> Result<(), Refusal> {
    check_len(field, obs.len(), s.obs_dim)?;
    check_finite(field, obs)?;
    check_unit(field, &obs[..s.laser_dim])?;
    match check_magnitude(field, &obs[s.laser_dim..]) {
        Err(Refusal::Magnitude { field, index, value }) => Err(Refusal::Magnitude {
            field,
            index: index + s.laser_dim,
            value,
        }),
        other => other,
    }
}

/// Longest `host` (and other free-text identity strings) a registration may carry.
pub const MAX_NAME_BYTES: usize = 255;

/// Checks a free-text identity string of a registration (`host`): at most
/// [`MAX_NAME_BYTES`] bytes, printable ASCII without control characters (it ends up in logs).
pub fn check_name(field: &'static str, value: &str) -> Result<(), Refusal> {
    if value.len() > MAX_NAME_BYTES {
        return Err(Refusal::Name {
            field,
            why: format!("{} bytes, at most {MAX_NAME_BYTES} allowed", value.len()),
        });
    }
    if let Some(c) = value.chars().find(|c| !(c.is_ascii_graphic() || *c == ' ')) {
        return Err(Refusal::Name {
            field,
            why: format!("contains {c:?}; only printable ASCII is allowed"),
        });
    }
    Ok(())
}

/// Longest `actor_kind` a registration may carry.
pub const MAX_KIND_BYTES: usize = 32;

/// The actor kind a registration names: `"unknown"` when empty, else checked to be at most
/// [`MAX_KIND_BYTES`] printable ASCII bytes without spaces.
pub fn actor_kind(value: &str) -> Result<&str, Refusal> {
    if value.is_empty() {
        return Ok("unknown");
    }
    check_name("actor_kind", value)?;
    if value.len() > MAX_KIND_BYTES || value.contains(' ') {
        return Err(Refusal::Name {
            field: "actor_kind",
            why: format!("{value:?}: at most {MAX_KIND_BYTES} bytes without spaces"),
        });
    }
    Ok(value)
}

/// Checks the numbers of an episode report (run, actor and lease are checked by the learner):
/// the return, score and time finite and in range. The policy version is checked against the
/// newest published one by the learner, which knows it.
pub fn check_report(r: &pb::EpisodeReport) -> Result<(), Refusal> {
    let checks: [(&'static str, f64, bool, &'static str); 3] = [
        (
            "episode_return",
            r.episode_return,
            r.episode_return.abs() <= MAX_ABS_RETURN,
            "not a finite number within ±1e9",
        ),
        (
            "score",
            r.score,
            (0.0..=1.0).contains(&r.score),
            "not a BARN score in [0, 1]",
        ),
        (
            "time_s",
            r.time_s,
            (0.0..=MAX_EPISODE_TIME_S).contains(&r.time_s),
            "not a time in [0, 1e6] s",
        ),
    ];
    for (field, value, ok, expected) in checks {
        // NaN fails every comparison above, so `ok` is false for it.
        if !ok {
            return Err(Refusal::Report {
                field,
                value,
                expected,
            });
        }
    }
    if pb::Outcome::try_from(r.outcome).is_err() {
        return Err(Refusal::Report {
            field: "outcome",
            value: f64::from(r.outcome),
            expected: "not an Outcome (1 success, 2 collision, 3 timeout)",
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn validator() -> Validator {
        Validator {
            run_id: "run-a".into(),
            incarnation: 7,
            spaces: Spaces {
                obs_dim: 6,
                act_dim: 2,
                laser_dim: 4,
            },
        }
    }

    fn step<'a>(obs: &'a [f32], action: &'a [f32]) -> StepView<'a> {
        StepView {
            episode_id: 1,
            step_index: 0,
            policy_version: 0,
            obs,
            action,
            reward: -0.5,
            terminal: false,
            truncated: false,
            final_obs: &[],
        }
    }

    const OBS: [f32; 6] = [0.1, -1.0, 1.0, 0.0, 5.0, -3.0];

    #[test]
    fn accepts_a_good_step_and_a_truncated_one() {
        let v = validator();
        v.check_step(&step(&OBS, &[0.5, -1.0])).unwrap();
        let mut s = step(&OBS, &[0.5, -1.0]);
        s.truncated = true;
        s.final_obs = &OBS;
        v.check_step(&s).unwrap();
    }

    #[test]
    fn refuses_each_defect_with_a_message_naming_it() {
        let v = validator();
        let cases: Vec<(StepView<'_>, RefusalKind, &str)> = vec![
            (
                step(&OBS[..5], &[0.0, 0.0]),
                RefusalKind::Shape,
                "`obs` has 5 values, expected 6",
            ),
            (step(&OBS, &[0.0]), RefusalKind::Shape, "`action` has 1 values"),
            (
                step(&[0.1, f32::NAN, 0.0, 0.0, 0.0, 0.0], &[0.0, 0.0]),
                RefusalKind::NotFinite,
                "`obs`[1] is not finite",
            ),
            (step(&OBS, &[0.0, 1.5]), RefusalKind::Range, "`action`[1] = 1.5"),
            (
                step(&[0.1, 0.0, 0.0, -1.2, 9.0, 9.0], &[0.0, 0.0]),
                RefusalKind::Range,
                "`obs`[3] = -1.2",
            ),
        ];
        let counts = RefusalCounts::default();
        for (s, kind, text) in cases {
            let e = v.check_step(&s).unwrap_err();
            assert_eq!(e.kind(), kind, "{e}");
            assert!(e.to_string().contains(text), "{e}");
            counts.record(&e, 1);
        }
        let mut s = step(&OBS, &[0.0, 0.0]);
        s.reward = f32::INFINITY;
        assert!(v.check_step(&s).unwrap_err().to_string().contains("`reward`"));
        s.reward = 0.0;
        s.terminal = true;
        s.truncated = true;
        s.final_obs = &OBS;
        assert_eq!(v.check_step(&s).unwrap_err().kind(), RefusalKind::Range);
        s.truncated = false;
        assert!(v
            .check_step(&s)
            .unwrap_err()
            .to_string()
            .contains("not truncated"));
        s.terminal = false;
        s.truncated = true;
        s.final_obs = &OBS[..2];
        assert!(v
            .check_step(&s)
            .unwrap_err()
            .to_string()
            .contains("`final_obs` has 2"));
        assert_eq!(counts.get(RefusalKind::Shape), 2);
        assert_eq!(counts.total(), 5);
    }

    #[test]
    fn refuses_absurd_magnitudes_of_unbounded_values() {
        let v = validator();
        let mut s = step(&OBS, &[0.0, 0.0]);
        s.reward = 1.0e30;
        let e = v.check_step(&s).unwrap_err();
        assert_eq!(e.kind(), RefusalKind::Range, "{e}");
        assert!(e.to_string().contains("`reward`[0]"), "{e}");
        // Index 5 is a non-laser value (laser_dim 4).
        let obs = [0.1, -1.0, 1.0, 0.0, 5.0, -3.0e9];
        let e = v.check_step(&step(&obs, &[0.0, 0.0])).unwrap_err();
        assert!(e.to_string().contains("`obs`[5]"), "{e}");
        let mut s = step(&OBS, &[0.0, 0.0]);
        s.truncated = true;
        s.final_obs = &obs;
        assert!(v
            .check_step(&s)
            .unwrap_err()
            .to_string()
            .contains("`final_obs`[5]"));
    }

    #[test]
    fn refuses_reports_with_non_finite_or_absurd_numbers() {
        let good = pb::EpisodeReport {
            episode_return: -120.5,
            score: 0.3,
            time_s: 22.0,
            ..Default::default()
        };
        check_report(&good).unwrap();
        let cases: [(pb::EpisodeReport, &str, RefusalKind); 7] = [
            (
                pb::EpisodeReport {
                    outcome: 9,
                    ..good.clone()
                },
                "outcome",
                RefusalKind::Range,
            ),
            (
                pb::EpisodeReport {
                    episode_return: f64::NAN,
                    ..good.clone()
                },
                "episode_return",
                RefusalKind::NotFinite,
            ),
            (
                pb::EpisodeReport {
                    episode_return: f64::INFINITY,
                    ..good.clone()
                },
                "episode_return",
                RefusalKind::NotFinite,
            ),
            (
                pb::EpisodeReport {
                    episode_return: -1.0e12,
                    ..good.clone()
                },
                "episode_return",
                RefusalKind::Range,
            ),
            (
                pb::EpisodeReport {
                    score: f64::NAN,
                    ..good.clone()
                },
                "score",
                RefusalKind::NotFinite,
            ),
            (
                pb::EpisodeReport {
                    score: 7.0,
                    ..good.clone()
                },
                "score",
                RefusalKind::Range,
            ),
            (
                pb::EpisodeReport {
                    time_s: f64::NEG_INFINITY,
                    ..good.clone()
                },
                "time_s",
                RefusalKind::NotFinite,
            ),
        ];
        for (r, field, kind) in cases {
            let e = check_report(&r).unwrap_err();
            assert_eq!(e.kind(), kind, "{e}");
            assert!(e.to_string().contains(&format!("`{field}`")), "{e}");
        }
    }

    #[test]
    fn registration_names_are_short_and_printable() {
        check_name("host", "node-17.cluster").unwrap();
        check_name("host", "").unwrap();
        let e = check_name("host", &"x".repeat(300)).unwrap_err();
        assert!(e.to_string().contains("300 bytes"), "{e}");
        let e = check_name("host", "evil\nlearner: fake log line").unwrap_err();
        assert!(e.to_string().contains("printable"), "{e}");
        assert_eq!(actor_kind("").unwrap(), "unknown");
        assert_eq!(actor_kind("python").unwrap(), "python");
        for bad in ["two words", "x\u{7}", &"k".repeat(33)] {
            let e = actor_kind(bad).unwrap_err();
            assert!(e.to_string().contains("actor_kind"), "{e}");
        }
    }

    #[test]
    fn run_and_incarnation_must_be_current() {
        let v = validator();
        v.check_run("run-a", 7).unwrap();
        let e = v.check_run("run-b", 7).unwrap_err();
        assert!(
            e.to_string().contains("`run-b`") && e.to_string().contains("`run-a`"),
            "{e}"
        );
        let e = v.check_run("run-a", 6).unwrap_err();
        assert_eq!(e.kind(), RefusalKind::Run);
        assert!(e.to_string().contains("stale incarnation 6"), "{e}");
    }
}
