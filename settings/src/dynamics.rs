//! The robot's response parameters as configuration: the named [`Profile`]s and the
//! [`Dynamics`] they stand for.
//!
//! Planners roll out a unicycle that reaches a commanded velocity at the controller's nominal
//! accelerations (20 m/s^2, 25 rad/s^2). A real Jackal, and its Gazebo model, does not: the
//! wheels track the command through a velocity loop (a first-order lag) bounded by what the
//! motors and tyre friction deliver, a skid-steer base turns less than its wheels ask for, commands
//! arrive a sense -> plan -> act latency after the scan they were planned on, and the pose the
//! robot believes in drifts from the truth as it drives. [`Dynamics`] holds those parameters
//! (each documented with its source); [`Profile`] names the presets. The simulator
//! (`sim::dynamics`) applies them to the robot one physics step at a time; here they are plain
//! data, so that the environment's settings ([`crate::env::EnvConfig`]) can name them without
//! the simulator.

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// The controller's nominal forward acceleration (m/s^2): `sim::RobotLimits::JACKAL.accel_v`,
/// which the simulator's tests check against.
const NOMINAL_ACCEL_V: f64 = 20.0;
/// The controller's nominal yaw acceleration (rad/s^2): `sim::RobotLimits::JACKAL.accel_w`.
const NOMINAL_ACCEL_W: f64 = 25.0;

/// A named robot-response preset.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Profile {
    /// The robot does exactly what the planners predict: the controller's nominal
    /// accelerations, exact arcs, no lag, slip, latency or drift; planners roll out exact arcs
    /// with conservative collision bounds. Kept so results stay comparable with earlier runs.
    Ideal,
    /// A Jackal as Gazebo simulates it (the papers' setting): see [`Dynamics::gazebo_jackal`].
    /// Planners roll out the papers' model (forward Euler, checks at grid points only).
    #[default]
    GazeboJackal,
    /// Parameters given explicitly in an `[episode.dynamics]` (or `[env.dynamics]`) table;
    /// planners roll out the papers' model.
    Custom,
}

impl Profile {
    /// The preset's parameters (`None` for [`Profile::Custom`], which has none).
    pub fn preset(self) -> Option<Dynamics> {
        match self {
            Profile::Ideal => Some(Dynamics::IDEAL),
            Profile::GazeboJackal => Some(Dynamics::gazebo_jackal()),
            Profile::Custom => None,
        }
    }

    /// The parameters this profile runs with: the preset, or `custom` for
    /// [`Profile::Custom`]. Errors name the table that is missing or out of place.
    pub fn resolve(self, custom: Option<&Dynamics>, table: &str) -> Result<Dynamics, ConfigError> {
        let table = table.to_string();
        match (self.preset(), custom) {
            (Some(d), None) => Ok(d),
            (None, Some(d)) => d.validate().map(|()| *d).map_err(|e| ConfigError::Table {
                table,
                source: Box::new(e),
            }),
            (None, None) => Err(ConfigError::MissingTable { table }),
            (Some(_), Some(_)) => Err(ConfigError::StrayTable {
                table,
                profile: self.name(),
            }),
        }
    }

    /// The name used in configs and tables.
    pub fn name(self) -> &'static str {
        match self {
            Profile::Ideal => "ideal",
            Profile::GazeboJackal => "gazebo-jackal",
            Profile::Custom => "custom",
        }
    }
}

/// How the simulated robot really responds (all in SI units). Plain data; `Copy`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Dynamics {
    /// Largest forward acceleration the drive delivers (m/s^2).
    pub accel_v: f64,
    /// Largest braking deceleration (m/s^2).
    pub decel_v: f64,
    /// Largest yaw acceleration of the wheels' turn command (rad/s^2).
    pub accel_w: f64,
    /// Time constant of the wheel velocity loop: the realized velocity approaches the command
    /// as a first-order lag, within the acceleration limits (s; 0 = none).
    pub lag_s: f64,
    /// Sense -> plan -> act latency: a command takes effect this long after the scan it was
    /// planned on (s; rounded to whole physics steps).
    pub latency_s: f64,
    /// Skid-steer yaw slip: the base turns at (1 - s) times the wheels' turn rate, with
    /// s = `slip_per_v` |v| + `slip_per_w` |w| (capped at `max_slip`). Per m/s.
    pub slip_per_v: f64,
    /// Yaw-slip growth with the turn rate (per rad/s).
    pub slip_per_w: f64,
    /// Cap of the yaw slip fraction.
    pub max_slip: f64,
    /// Outward side-slip in turns: lateral velocity = -`side_slip` v w (s).
    pub side_slip: f64,
    /// Localization drift: heading random walk, standard deviation per square root of metre
    /// driven (rad / sqrt(m)). The robot's costmap, global path and goals use the drifted pose.
    pub drift_yaw: f64,
    /// Localization drift: position random walk per axis (m / sqrt(m)).
    pub drift_pos: f64,
}

impl Dynamics {
    /// The planners' own model: nominal controller accelerations, nothing else.
    pub const IDEAL: Dynamics = Dynamics {
        accel_v: NOMINAL_ACCEL_V,
        decel_v: NOMINAL_ACCEL_V,
        accel_w: NOMINAL_ACCEL_W,
        lag_s: 0.0,
        latency_s: 0.0,
        slip_per_v: 0.0,
        slip_per_w: 0.0,
        max_slip: 0.0,
        side_slip: 0.0,
        drift_yaw: 0.0,
        drift_pos: 0.0,
    };

    /// A Jackal as Gazebo simulates it for the BARN benchmark. Sources:
    /// - accelerations: the wheels' Coulomb friction in the Jackal's Gazebo description
    ///   (`mu1 = mu2 = 0.5`, jackal_description) bounds the traction of a 17.4 kg robot at
    ///   mu g = 4.9 m/s^2; the motors deliver less than that from standstill, so forward
    ///   acceleration is taken at 2.5 m/s^2 and braking at the traction bound less rolling
    ///   losses, 4.0 m/s^2. The yaw acceleration is bounded the same way: friction at the
    ///   wheel contacts, half the track (0.188 m) from the centre, against the base's yaw
    ///   inertia gives about 8 rad/s^2.
    /// - lag: 0.10 s, the time constant of a velocity-controlled wheel joint (the diff-drive
    ///   controller's PID on Gazebo's ODE contacts at the Jackal's mass); the controller's
    ///   nominal 20 m/s^2 is never seen.
    /// - latency: 0.075 s, the mean age of a command's data when it reaches the wheels: half a
    ///   scan period at 40 Hz (Hokuyo UST-10, 12.5 ms), half a 20 Hz planning period plus the
    ///   planning itself (25 + ~25 ms), and half the velocity controller's 50 Hz period
    ///   (10 ms).
    /// - yaw slip: the Jackal's diff-drive controller multiplies the wheel separation by 1.5
    ///   (jackal_control `control.yaml`) to cancel the skid-steer base's average slip; the
    ///   residual grows with speed and turn rate: 8 % per m/s plus 6 % per rad/s, capped at
    ///   40 %.
    /// - side slip: 0.03 s (3 cm/s outward at 1 m/s and 1 rad/s).
    /// - drift: the EKF fuses wheel odometry with an IMU whose heading drifts (hector IMU
    ///   plugin, `headingDrift` 0.005); 0.01 rad and 0.01 m per square root of metre driven.
    pub fn gazebo_jackal() -> Dynamics {
        Dynamics {
            accel_v: 2.5,
            decel_v: 4.0,
            accel_w: 8.0,
            lag_s: 0.10,
            latency_s: 0.075,
            slip_per_v: 0.08,
            slip_per_w: 0.06,
            max_slip: 0.4,
            side_slip: 0.03,
            drift_yaw: 0.01,
            drift_pos: 0.01,
        }
    }

    /// Checks every value; the error names the field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let positive = [
            ("accel_v", self.accel_v),
            ("decel_v", self.decel_v),
            ("accel_w", self.accel_w),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(ConfigError::value(name, v, "must be finite and > 0"));
            }
        }
        let non_negative = [
            ("lag_s", self.lag_s),
            ("latency_s", self.latency_s),
            ("slip_per_v", self.slip_per_v),
            ("slip_per_w", self.slip_per_w),
            ("side_slip", self.side_slip),
            ("drift_yaw", self.drift_yaw),
            ("drift_pos", self.drift_pos),
        ];
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ConfigError::value(name, v, "must be finite and >= 0"));
            }
        }
        if !(0.0..1.0).contains(&self.max_slip) {
            return Err(ConfigError::value("max_slip", self.max_slip, "must be in [0, 1)"));
        }
        if self.latency_s > 1.0 {
            return Err(ConfigError::value(
                "latency_s",
                self.latency_s,
                "must be at most 1 s",
            ));
        }
        Ok(())
    }

    /// The yaw slip fraction at wheel-level velocity (v, w).
    pub fn slip(&self, v: f64, w: f64) -> f64 {
        (self.slip_per_v * v.abs() + self.slip_per_w * w.abs()).min(self.max_slip)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles_resolve_and_refuse_misplaced_tables() {
        assert_eq!(
            Profile::Ideal.resolve(None, "episode.dynamics"),
            Ok(Dynamics::IDEAL)
        );
        let custom = Dynamics {
            lag_s: 0.3,
            ..Dynamics::IDEAL
        };
        assert_eq!(
            Profile::Custom.resolve(Some(&custom), "episode.dynamics"),
            Ok(custom)
        );
        let e = Profile::Custom
            .resolve(None, "env.dynamics")
            .unwrap_err()
            .to_string();
        assert!(e.contains("[env.dynamics]"), "{e}");
        let e = Profile::GazeboJackal
            .resolve(Some(&custom), "episode.dynamics")
            .unwrap_err()
            .to_string();
        assert!(e.contains("profile = \"custom\""), "{e}");
        let bad = Dynamics {
            max_slip: 1.5,
            ..Dynamics::IDEAL
        };
        let e = Profile::Custom
            .resolve(Some(&bad), "episode.dynamics")
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_slip"), "{e}");
        assert!(Dynamics::gazebo_jackal().validate().is_ok());
    }
}
