//! The RL environment's settings (the `[env]` table of a training configuration, sent to
//! the actors in the run spec): agent rate, step cap, laser clip and layout, reward terms,
//! action map, robot profile, compute model, observed tracks and domain randomization.
//!
//! The environment itself (`actor::AdpEnv`: a BARN episode driven by a planner) reads them;
//! the learner validates them, records them in checkpoints and puts them on the wire without
//! knowing the simulator or the planners.

use layout::{LaserLayout, DEFAULT_LASER_CLIP_M, MAX_OBSERVED_TRACKS};
use serde::{Deserialize, Serialize};

use crate::action::ActionMap;
use crate::compute::ComputeConfig;
use crate::dynamics::{Dynamics, Profile};

/// Environment parameters: agent rate, step cap, laser clip and the reward terms.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnvConfig {
    /// Planner cycles per agent step (default 5: 0.25 s at the 0.05 s control period).
    pub agent_period_cycles: u32,
    /// Agent steps before the episode is truncated (default 200: 50 s, the training cap).
    pub max_agent_steps: u32,
    /// Laser ranges are clipped here before encoding (m; default 3.0).
    pub laser_clip_m: f64,
    /// Reward per metre of progress toward the global goal (default 10.0).
    pub progress_scale: f64,
    /// Reward added every step (default -0.5).
    pub step_penalty: f64,
    /// The obstacle penalty applies when the robot's clearance (the mean of the 10 smallest
    /// distances from its footprint's boundary to the lidar returns) is below this (m; default
    /// 0.2: about half the Jackal's width, where DWA's and MPPI's obstacle costs start).
    pub obstacle_threshold_m: f64,
    /// Obstacle penalty at zero clearance; it falls quadratically to 0 at the threshold
    /// (default -5.0: a twentieth of a collision per 0.25 s touching).
    pub obstacle_scale: f64,
    /// Reward of the step that collides (default -100.0).
    pub collision_reward: f64,
    /// Added to the shaping reward of the step that hits the step cap or the simulator's
    /// timeout (default 0.0). The learner bootstraps through such a step (the state has no
    /// clock), so a non-zero value is noise to the critic; it is kept for ablations.
    pub timeout_reward: f64,
    /// Agent steps over which the stuck term measures progress toward the goal (default 0:
    /// no stuck term). The 3D RL-DWA paper's `R_stuck` looks at its last 20 steps.
    pub stuck_window: u32,
    /// A robot that got less than this much closer to the goal (Euclidean, m) over the last
    /// `stuck_window` agent steps is stuck (default 0.5).
    pub stuck_progress_m: f64,
    /// Added to the shaping reward of every step after which the robot is stuck (default 0.0;
    /// negative for a penalty). Not added to a colliding step, whose reward replaces shaping.
    pub stuck_reward: f64,
    /// Added to the shaping reward of the step that reaches the goal (default 50.0).
    pub success_reward: f64,
    /// Every reward is multiplied by this before it is stored (default 0.01: collision -1,
    /// success +0.5, a metre of progress +0.1), so returns are O(1) at the learning rates of
    /// `[td3]`, which the authors tuned on normalized rewards. Episode returns in reports and
    /// status are in these scaled units.
    pub reward_scale: f64,
    /// How the policy's output becomes a schedule (`ddp-centred` (default): output 0 is the
    /// DDP schedule; `affine`: the paper's box, where DDP is a corner). See [`ActionMap`].
    pub action_map: ActionMap,
    /// The simulator profile the episodes run on (`ideal`, `gazebo-jackal` (default) or
    /// `custom`): the robot's true response and the planners' rollout model. It overrides the
    /// episode settings' profile, so checkpoints and the policy card record what the policy
    /// was trained on.
    pub profile: Profile,
    /// The response parameters of `profile = "custom"` (a `[env.dynamics]` table; absent
    /// otherwise).
    pub dynamics: Option<Dynamics>,
    /// The onboard compute model the planner runs under (`[env.compute]`; default
    /// `jackal-onboard-v2`: a cycle budget, and the command acts after the modelled compute;
    /// `model = "free"` prices nothing). See [`crate::compute`].
    pub compute: ComputeConfig,
    /// Moving tracks in the observation (default 0: none, the layout of every policy trained
    /// before tracks existed). With `k > 0` every planning cycle runs the obstacle tracker
    /// (`planner::CycleDriver::with_tracking`): the planner checks its rollouts against the
    /// tracks' forecast, and the observation ends with the `k` nearest of them (the `tracks`
    /// segment of [`layout::observation`]). At most [`MAX_OBSERVED_TRACKS`].
    pub observe_tracks: usize,
    /// The laser segment's layout (`"scan"`, the default: the 720 ranges; `"sectors:N"`: the
    /// least range in each of N equal sectors of the 270-degree field). The observation is
    /// built in this layout from whatever the lidar gives (any beam count, resampled: see
    /// `actor::LaserResampler`).
    pub observation: LaserLayout,
    /// Domain randomization of the sensing conditions, drawn per episode (`[env.randomize]`;
    /// off by default).
    pub randomize: Randomize,
}

/// Most beam counts [`Randomize::beams`] may list.
pub const MAX_BEAM_CHOICES: usize = 8;

/// Beam counts to draw from (at most [`MAX_BEAM_CHOICES`]; a TOML list, e.g. `[90, 360,
/// 720]`). Fixed-size, so that [`EnvConfig`] stays `Copy`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "Vec<usize>", into = "Vec<usize>")]
pub struct BeamChoices {
    len: usize,
    values: [usize; MAX_BEAM_CHOICES],
}

impl BeamChoices {
    /// The listed beam counts, in order.
    pub fn as_slice(&self) -> &[usize] {
        &self.values[..self.len]
    }
}

impl TryFrom<Vec<usize>> for BeamChoices {
    type Error = RandomizeError;

    fn try_from(v: Vec<usize>) -> Result<Self, RandomizeError> {
        if v.len() > MAX_BEAM_CHOICES {
            return Err(RandomizeError::TooManyBeams { count: v.len() });
        }
        let mut values = [0; MAX_BEAM_CHOICES];
        values[..v.len()].copy_from_slice(&v);
        Ok(Self { len: v.len(), values })
    }
}

impl From<BeamChoices> for Vec<usize> {
    fn from(b: BeamChoices) -> Vec<usize> {
        b.as_slice().to_vec()
    }
}

/// Domain randomization of the lidar's sensing conditions (`[env.randomize]`), a training
/// option: every episode draws its own beam count, noise and dropout from the environment's
/// seed (which the scheduler derives from the run seed, the actor's rank and the episode
/// count) on a stream of its own, in that order, each only when given. Off by default: nothing
/// is drawn and the episode's `[episode.lidar]` applies. Evaluation turns it off
/// ([`EnvConfig::for_evaluation`]): rows run the evaluation's own lidar. The actor draws an
/// episode's lidar (`actor::env::RandomizeLidar`); here are the settings and their checks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Randomize {
    /// Beam counts to draw from, uniformly (empty: the episode's own).
    pub beams: BeamChoices,
    /// `[low, high]`: the noise fraction (sigma as a fraction of each scan's mean range) drawn
    /// uniformly in it; it replaces the episode's absolute noise (`noise_sigma` becomes 0).
    /// Absent: the episode's noise.
    pub noise_fraction: Option<[f64; 2]>,
    /// `[low, high]`: the beam dropout probability drawn uniformly in it. Absent: the
    /// episode's.
    pub dropout: Option<[f64; 2]>,
}

/// A `[env.randomize]` value out of range (from [`EnvConfig::validate`], or reading a
/// [`BeamChoices`]); the message names the field (`randomize.<field>`) and the value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RandomizeError {
    /// `beams` lists more than [`MAX_BEAM_CHOICES`] beam counts.
    #[error("randomize.beams lists {count} beam counts; at most {MAX_BEAM_CHOICES}")]
    TooManyBeams {
        /// How many it lists.
        count: usize,
    },
    /// `beams` lists a beam count below 2.
    #[error("randomize.beams = {beams:?}: {beam} beams is too few (at least 2)")]
    TooFewBeams {
        /// The listed beam counts.
        beams: Vec<usize>,
        /// The first one below 2.
        beam: usize,
    },
    /// `noise_fraction` is not a range `low <= high` within [0, 1].
    #[error("randomize.noise_fraction = [{low}, {high}] must be a range low <= high within [0, 1]")]
    NoiseFraction {
        /// The range's low end.
        low: f64,
        /// The range's high end.
        high: f64,
    },
    /// `dropout` is not a range `low <= high` within [0, 1).
    #[error("randomize.dropout = [{low}, {high}] must be a range low <= high within [0, 1)")]
    Dropout {
        /// The range's low end.
        low: f64,
        /// The range's high end.
        high: f64,
    },
}

impl Randomize {
    /// Whether it draws anything.
    pub fn is_on(&self) -> bool {
        !self.beams.as_slice().is_empty() || self.noise_fraction.is_some() || self.dropout.is_some()
    }

    /// Checks the values; the error names the field and the value.
    fn validate(&self) -> Result<(), RandomizeError> {
        if let Some(&beam) = self.beams.as_slice().iter().find(|&&b| b < 2) {
            return Err(RandomizeError::TooFewBeams {
                beams: self.beams.as_slice().to_vec(),
                beam,
            });
        }
        if let Some([low, high]) = self.noise_fraction {
            if !(0.0 <= low && low <= high && high <= 1.0) {
                return Err(RandomizeError::NoiseFraction { low, high });
            }
        }
        if let Some([low, high]) = self.dropout {
            if !(0.0 <= low && low <= high && high < 1.0) {
                return Err(RandomizeError::Dropout { low, high });
            }
        }
        Ok(())
    }
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            agent_period_cycles: 5,
            max_agent_steps: 200,
            laser_clip_m: DEFAULT_LASER_CLIP_M,
            progress_scale: 10.0,
            step_penalty: -0.5,
            obstacle_threshold_m: 0.2,
            obstacle_scale: -5.0,
            collision_reward: -100.0,
            timeout_reward: 0.0,
            stuck_window: 0,
            stuck_progress_m: 0.5,
            stuck_reward: 0.0,
            success_reward: 50.0,
            reward_scale: 0.01,
            action_map: ActionMap::DdpCentred,
            profile: Profile::default(),
            dynamics: None,
            compute: ComputeConfig::default(),
            observe_tracks: 0,
            observation: LaserLayout::Scan,
            randomize: Randomize::default(),
        }
    }
}

impl EnvConfig {
    /// These settings for evaluating a policy trained with them: no agent-step cap (runs end
    /// by the BARN protocol of `[episode]`, like every other evaluation row) and no domain
    /// randomization (the evaluation's own lidar applies).
    pub fn for_evaluation(self) -> Self {
        Self {
            max_agent_steps: u32::MAX,
            randomize: Randomize::default(),
            ..self
        }
    }

    /// Checks the values; the error names the offending field.
    pub fn validate(&self) -> Result<(), EnvConfigError> {
        let bad = |msg: String| Err(EnvConfigError::Config(msg));
        if self.agent_period_cycles == 0 {
            return bad("agent_period_cycles must be >= 1".into());
        }
        if self.max_agent_steps == 0 {
            return bad("max_agent_steps must be >= 1".into());
        }
        for (name, v) in [
            ("laser_clip_m", self.laser_clip_m),
            ("obstacle_threshold_m", self.obstacle_threshold_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{name} = {v} must be finite and > 0"));
            }
        }
        for (name, v) in [
            ("progress_scale", self.progress_scale),
            ("step_penalty", self.step_penalty),
            ("obstacle_scale", self.obstacle_scale),
            ("collision_reward", self.collision_reward),
            ("timeout_reward", self.timeout_reward),
            ("stuck_progress_m", self.stuck_progress_m),
            ("stuck_reward", self.stuck_reward),
            ("success_reward", self.success_reward),
        ] {
            if !v.is_finite() {
                return bad(format!("{name} = {v} must be finite"));
            }
        }
        if self.observe_tracks > MAX_OBSERVED_TRACKS {
            return bad(format!(
                "observe_tracks = {} must be at most {}",
                self.observe_tracks, MAX_OBSERVED_TRACKS
            ));
        }
        self.randomize.validate()?;
        if !(self.reward_scale.is_finite() && self.reward_scale > 0.0) {
            return bad(format!(
                "reward_scale = {} must be finite and > 0",
                self.reward_scale
            ));
        }
        self.compute
            .validate()
            .map_err(|e| EnvConfigError::Config(format!("env.{e}")))?;
        self.profile
            .resolve(self.dynamics.as_ref(), "env.dynamics")
            .map(|_| ())
            .map_err(|e| EnvConfigError::Config(e.to_string()))
    }
}

/// Environment settings that cannot work ([`EnvConfig::validate`]); the message names the
/// field. The actor's `EnvError` has the same two variants, with the same messages.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvConfigError {
    /// A configuration value is out of range (the message names it).
    #[error("invalid environment configuration: {0}")]
    Config(String),
    /// A `[env.randomize]` value is out of range (the error names the field).
    #[error("invalid environment configuration: {0}")]
    Randomize(#[from] RandomizeError),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bad `[env.randomize]` value is the typed [`EnvConfigError::Randomize`], whose variant is
    /// the field and whose message names it with the value.
    #[test]
    fn bad_randomization_is_refused_by_name() {
        let err = |r: Randomize| {
            EnvConfig {
                randomize: r,
                ..EnvConfig::default()
            }
            .validate()
            .unwrap_err()
        };
        let e = err(Randomize {
            beams: vec![720, 1].try_into().unwrap(),
            ..Randomize::default()
        });
        assert_eq!(
            e,
            EnvConfigError::Randomize(RandomizeError::TooFewBeams {
                beams: vec![720, 1],
                beam: 1
            })
        );
        assert_eq!(
            e.to_string(),
            "invalid environment configuration: randomize.beams = [720, 1]: 1 beams is too few (at least 2)"
        );
        let e = err(Randomize {
            noise_fraction: Some([0.2, 0.1]),
            ..Randomize::default()
        });
        assert_eq!(
            e,
            EnvConfigError::Randomize(RandomizeError::NoiseFraction { low: 0.2, high: 0.1 })
        );
        assert_eq!(
            e.to_string(),
            "invalid environment configuration: randomize.noise_fraction = [0.2, 0.1] must be a range \
             low <= high within [0, 1]"
        );
        let e = err(Randomize {
            dropout: Some([0.0, 1.0]),
            ..Randomize::default()
        });
        assert_eq!(
            e,
            EnvConfigError::Randomize(RandomizeError::Dropout { low: 0.0, high: 1.0 })
        );
        assert!(e
            .to_string()
            .contains("randomize.dropout = [0, 1] must be a range low <= high within [0, 1)"));
        assert_eq!(
            BeamChoices::try_from(vec![90; 9]),
            Err(RandomizeError::TooManyBeams { count: 9 })
        );
        let too_many = toml::from_str::<EnvConfig>("[randomize]\nbeams = [2, 3, 4, 5, 6, 7, 8, 9, 10]\n")
            .unwrap_err()
            .to_string();
        assert!(
            too_many.contains("randomize.beams lists 9 beam counts; at most 8"),
            "{too_many}"
        );
    }
}
