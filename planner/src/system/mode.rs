//! The mode state machine (normal, low speed, brake, recovery with rotate-in-place and
//! back-up), after the authors' `velocityCallback`; it keeps time by counting planning cycles.

use super::SystemConfig;

/// The driving mode of the navigation system.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Full speed cap; sampling with the normal costs.
    Normal,
    /// Half the speed cap, wider yaw-rate caps, a closer local goal and a free-space cost.
    LowSpeed,
    /// Stopping before recovery.
    Brake,
    /// Sampling with slow creeping and turning candidates.
    Recovery,
    /// Recovery: rotating in place toward the local path.
    Rotate,
    /// Recovery: backing up slowly while the front is blocked, then rotating.
    Backup,
}

/// What the mode machine observes at the start of a cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModeObservation {
    /// Measured forward speed (m/s).
    pub speed: f64,
    /// The run's speed cap (m/s).
    pub max_speed: f64,
    /// Free distance ahead of the bumper, within the robot's width plus a side margin (m).
    pub front_clearance: f64,
    /// Heading error to the mean bearing of the local path (rad).
    pub heading_error: f64,
}

/// The mode state machine. Pure: it sees measured speeds, the front clearance, the heading
/// error and whether the current mode's action was possible, and keeps time by counting
/// cycles of `control_dt` seconds.
#[derive(Clone, Debug)]
pub struct ModeMachine {
    cfg: SystemConfig,
    mode: Mode,
    /// Cycles since entering the current mode.
    mode_cycles: u32,
    /// Cycles the current mode's "too slow" condition has held.
    slow_cycles: u32,
    /// Cycles the low-speed mode's "fast again" condition has held.
    fast_cycles: u32,
    /// Successful recovery cycles since entering recovery.
    successes: u32,
    /// Recovery level: `level * recovery_successes` successes end a recovery.
    level: u32,
}

/// Tolerance on accumulated cycle times (s).
const TIME_EPS: f64 = 1e-9;

impl ModeMachine {
    /// A machine in normal mode.
    pub fn new(cfg: SystemConfig) -> Self {
        Self {
            cfg,
            mode: Mode::Normal,
            mode_cycles: 0,
            slow_cycles: 0,
            fast_cycles: 0,
            successes: 0,
            level: 1,
        }
    }

    /// The current mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    fn held(&self, cycles: u32) -> f64 {
        cycles as f64 * self.cfg.control_dt
    }

    fn enter(&mut self, mode: Mode) -> Mode {
        self.mode = mode;
        self.mode_cycles = 0;
        self.slow_cycles = 0;
        self.fast_cycles = 0;
        match mode {
            Mode::Normal => self.level = 1,
            Mode::Recovery => self.successes = 0,
            _ => {}
        }
        mode
    }

    /// Advances the clock by one cycle and applies the speed, front and heading rules:
    /// normal -> low-speed after `mode_wait` below `enter_low_frac * cap + enter_low_offset`;
    /// low-speed -> normal after `mode_wait` at or above `enter_normal_frac * low cap +
    /// enter_normal_offset` (the low-speed cap: the full cap's threshold is unreachable
    /// there); low-speed -> brake after more than `mode_wait` below `min_speed`; brake ->
    /// recovery once stopped; recovery -> back-up when the front is blocked; back-up ->
    /// rotate once the front is clear (after `backup_min_time`, at most `backup_max_time`);
    /// rotate -> low-speed when facing the local path.
    pub fn update(&mut self, obs: &ModeObservation) -> Mode {
        let c = self.cfg;
        let v = obs.speed;
        self.mode_cycles += 1;
        match self.mode {
            Mode::Normal => {
                if v < c.enter_low_frac * obs.max_speed + c.enter_low_offset {
                    self.slow_cycles += 1;
                    if self.held(self.slow_cycles) >= c.mode_wait - TIME_EPS {
                        return self.enter(Mode::LowSpeed);
                    }
                } else {
                    self.slow_cycles = 0;
                }
            }
            Mode::LowSpeed => {
                let cap = c.low_speed_scale * obs.max_speed;
                if v >= c.enter_normal_frac * cap + c.enter_normal_offset {
                    self.fast_cycles += 1;
                    if self.held(self.fast_cycles) >= c.mode_wait - TIME_EPS {
                        return self.enter(Mode::Normal);
                    }
                } else {
                    self.fast_cycles = 0;
                }
                if v < c.min_speed {
                    self.slow_cycles += 1;
                    if self.held(self.slow_cycles) > c.mode_wait + TIME_EPS {
                        return self.enter(Mode::Brake);
                    }
                } else {
                    self.slow_cycles = 0;
                }
            }
            Mode::Brake => {
                if v.abs() <= c.stopped_speed {
                    return self.enter(Mode::Recovery);
                }
            }
            Mode::Recovery => {
                if obs.front_clearance <= c.front_blocked {
                    return self.enter(Mode::Backup);
                }
            }
            Mode::Backup => {
                let held = self.held(self.mode_cycles);
                if (obs.front_clearance >= c.front_clear && held >= c.backup_min_time - TIME_EPS)
                    || held >= c.backup_max_time - TIME_EPS
                {
                    return self.enter(Mode::Rotate);
                }
            }
            Mode::Rotate => {
                if obs.heading_error.abs() <= c.rotate_tolerance {
                    return self.enter(Mode::LowSpeed);
                }
            }
        }
        self.mode
    }

    /// Reports whether the current mode's action was possible this cycle (a collision-free
    /// sample, a clear rotation or back-up) and applies the outcome rules: a successful
    /// recovery returns to low-speed after `level * recovery_successes` cycles (the level
    /// grows with each recovery up to `recovery_max_level` and resets in normal mode); a
    /// failure degrades normal -> low-speed -> brake, and cycles recovery -> rotate ->
    /// back-up -> recovery.
    pub fn report(&mut self, ok: bool) -> Mode {
        match (self.mode, ok) {
            (Mode::Recovery, true) => {
                self.successes += 1;
                if self.successes >= self.cfg.recovery_successes * self.level {
                    self.level = (self.level + 1).min(self.cfg.recovery_max_level.max(1));
                    return self.enter(Mode::LowSpeed);
                }
            }
            (Mode::Normal, false) => return self.enter(Mode::LowSpeed),
            (Mode::LowSpeed, false) => return self.enter(Mode::Brake),
            (Mode::Recovery, false) => return self.enter(Mode::Rotate),
            (Mode::Rotate, false) => return self.enter(Mode::Backup),
            (Mode::Backup, false) => return self.enter(Mode::Recovery),
            _ => {}
        }
        self.mode
    }
}
