//! ADP action spaces ([`settings::action`], re-exported here), and the one mapping that needs
//! the simulator: a velocity-space action to the command the robot runs
//! ([`VelocityCommand`]).

use sim::robot::Twist;

pub use settings::action::*;

/// The command of a velocity-space action, as a [`Twist`] (the one part of the action spaces
/// that needs the simulator's types).
pub trait VelocityCommand {
    /// The command of a velocity-space action: `v = v_frac * max_speed` (v_frac in [0, 1]),
    /// `w` in [-[`VELOCITY_MAX_W`], [`VELOCITY_MAX_W`]] (clamped first, like every action).
    /// Refuses another space's action (the error says the velocity space needs 2 values when
    /// the length differs) and non-finite values.
    fn velocity_command(self, action: &[f64], max_speed: f64) -> Result<Twist, ActionError>;
}

impl VelocityCommand for ActionSpace {
    fn velocity_command(self, action: &[f64], max_speed: f64) -> Result<Twist, ActionError> {
        if self != ActionSpace::Velocity {
            return Err(ActionError::Dim {
                space: ActionSpace::Velocity,
                expected: 2,
                got: action.len(),
            });
        }
        let q = self.to_params(action)?;
        Ok(Twist::new(q[0] * max_speed, q[1]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn velocity_maps_onto_the_speed_cap_and_the_yaw_rate_bound() {
        let v = ActionSpace::Velocity;
        assert_eq!(v.velocity_command(&[0.0, 0.0], 1.5), Ok(Twist::new(0.75, 0.0)));
        assert_eq!(v.velocity_command(&[1.0, -1.0], 1.5), Ok(Twist::new(1.5, -2.0)));
        // Clamped: never backwards, never beyond the bounds.
        assert_eq!(v.velocity_command(&[-3.0, 9.0], 0.5), Ok(Twist::new(0.0, 2.0)));
        assert!(matches!(
            v.velocity_command(&[f64::NAN, 0.0], 1.0),
            Err(ActionError::NotFinite { name: "v_frac", .. })
        ));
        assert!(ActionSpace::Decremental.velocity_command(&[0.0; 4], 1.0).is_err());
    }
}
