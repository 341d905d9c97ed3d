//! The navigation system's parameters.

use serde::{Deserialize, Serialize};

/// Navigation-system parameters (defaults used by `adp eval`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SystemConfig {
    /// Linear-velocity grid points across the dynamic window.
    pub v_samples: usize,
    /// Angular-velocity grid points across the dynamic window.
    pub w_samples: usize,
    /// Samples whose nominal command is the previous solution (warm start).
    pub warm_samples: usize,
    /// Samples per mode-specific extra command (low-speed creep, recovery creep and turns).
    pub extra_samples: usize,
    /// Standard deviation of the per-step noise on the linear velocity (m/s).
    pub noise_v: f64,
    /// Standard deviation of the per-step noise on the angular velocity (rad/s).
    pub noise_w: f64,
    /// Number of cheapest collision-free samples averaged.
    pub top_k: usize,
    /// Temperature of the cost weights of the averaged samples.
    pub lambda: f64,
    /// Linear acceleration assumed in rollouts and the window (m/s^2).
    pub accel_v: f64,
    /// Angular acceleration assumed in rollouts and the window (rad/s^2).
    pub accel_w: f64,
    /// The window spans what is reachable in this time (s): one control period.
    pub window_dt: f64,
    /// One planning cycle (s): the mode machine's clock advances this much per call.
    pub control_dt: f64,
    /// Speed cap of low-speed and recovery modes, as a fraction of the run's cap.
    pub low_speed_scale: f64,
    /// Yaw-rate caps in normal mode (rad/s): slow and gentle, moderate, fast.
    pub normal_max_w: [f64; 3],
    /// Yaw-rate caps in low-speed and recovery modes (rad/s): slow and gentle, moderate, fast.
    pub low_max_w: [f64; 3],
    /// Normal -> low-speed when the speed stays below `enter_low_frac * cap + enter_low_offset`.
    pub enter_low_frac: f64,
    /// See `enter_low_frac` (m/s).
    pub enter_low_offset: f64,
    /// Low-speed -> normal when the speed stays at or above
    /// `enter_normal_frac * low-speed cap + enter_normal_offset`.
    pub enter_normal_frac: f64,
    /// See `enter_normal_frac` (m/s).
    pub enter_normal_offset: f64,
    /// Low-speed -> brake when the speed stays below this (m/s).
    pub min_speed: f64,
    /// How long a speed condition must hold before the mode changes (s).
    pub mode_wait: f64,
    /// Brake -> recovery once the measured speed is at most this (m/s).
    pub stopped_speed: f64,
    /// Front clearance = free distance ahead of the bumper within the footprint's width plus
    /// this much either side (m).
    pub front_side_margin: f64,
    /// Recovery -> back-up when the front clearance is at most this (m).
    pub front_blocked: f64,
    /// Back-up -> rotate (toward the local path) when the front clearance is at least this (m).
    pub front_clear: f64,
    /// Back-up speed (m/s, positive).
    pub backup_speed: f64,
    /// Shortest back-up (s).
    pub backup_min_time: f64,
    /// Longest back-up (s): the lidar does not see behind the robot.
    pub backup_max_time: f64,
    /// Smallest yaw rate of rotate-in-place (rad/s).
    pub rotate_min_w: f64,
    /// Largest yaw rate of rotate-in-place (rad/s).
    pub rotate_max_w: f64,
    /// Rotate -> low-speed when the heading error to the local path is at most this (rad).
    pub rotate_tolerance: f64,
    /// Successful recovery cycles per recovery level before returning to low-speed.
    pub recovery_successes: u32,
    /// Largest recovery level (the required successes grow with each recovery).
    pub recovery_max_level: u32,
    /// Speed of the low-speed mode's creep samples (m/s).
    pub low_creep_v: f64,
    /// Speed of the recovery mode's straight creep samples (m/s).
    pub recovery_creep_v: f64,
    /// Speed of the recovery mode's turning samples (m/s).
    pub recovery_turn_v: f64,
    /// Yaw rate of the recovery mode's turning samples (rad/s, both signs).
    pub recovery_turn_w: f64,
    /// Weight of the distance to the local goal (normal mode).
    pub normal_goal: f64,
    /// Weight of the obstacle-proximity cost (normal mode).
    pub normal_obstacle: f64,
    /// Weight of the heading error to the local goal (normal mode).
    pub normal_heading: f64,
    /// Weight of the lack of free space ahead (normal mode).
    pub normal_space: f64,
    /// Weight of the distance to the local goal (low-speed and recovery).
    pub low_goal: f64,
    /// Weight of the obstacle-proximity cost (low-speed and recovery).
    pub low_obstacle: f64,
    /// Weight of the heading error to the local goal (low-speed and recovery).
    pub low_heading: f64,
    /// Weight of the lack of free space ahead (low-speed and recovery).
    pub low_space: f64,
    /// Smallest estimated clearance of a feasible rollout in normal mode (m).
    pub normal_margin: f64,
    /// Smallest estimated clearance of a feasible rollout in the other modes, and smallest
    /// exact clearance of the rotate-in-place and back-up motions (m).
    pub low_margin: f64,
    /// Shortest travel over the horizon of a feasible rollout in normal mode (m).
    pub normal_min_travel: f64,
    /// Shortest travel over the horizon of a feasible rollout in low-speed mode (m).
    pub low_min_travel: f64,
    /// Shortest travel over the horizon of a feasible rollout in recovery mode (m).
    pub recovery_min_travel: f64,
    /// Low-speed and recovery local goal: as far along the local path as the speed cap
    /// reaches over the horizon, plus this (m).
    pub low_goal_offset: f64,
    /// In low-speed and recovery modes a rollout may stop before its first failed check
    /// if it has driven collision-free for at least this long (s).
    pub low_min_safe_time: f64,
    /// Clearances above this cost nothing (m).
    pub clearance_cap: f64,
    /// Free space ahead beyond this costs nothing (m).
    pub space_cap: f64,
    /// The free space is the least of three rays: ahead and this far either side (degrees).
    pub space_half_angle_deg: f64,
    /// The averaged command must stay collision-free over this much of the rollout (s).
    pub verify_time: f64,
    /// Among moving obstacles, a feasible rollout must end where the robot could stop and
    /// stay clear of the obstacles' forecast for this long after the horizon (s; a
    /// passive-safety check, see the sampling's `evaluate`). Without a forecast (static
    /// worlds) it plays no part.
    pub moving_hold_time: f64,
    /// Distance-field cell size (m).
    pub map_resolution: f64,
}

impl Default for SystemConfig {
    fn default() -> Self {
        Self {
            v_samples: 22,
            w_samples: 24,
            warm_samples: 22,
            extra_samples: 25,
            noise_v: 0.05,
            noise_w: 0.05,
            top_k: 10,
            lambda: 1.0,
            accel_v: 20.0,
            accel_w: 25.0,
            window_dt: 0.05,
            control_dt: 0.05,
            low_speed_scale: 0.5,
            normal_max_w: [2.0, 1.5, 1.0],
            low_max_w: [2.5, 2.0, 1.5],
            enter_low_frac: 0.5,
            enter_low_offset: 0.1,
            enter_normal_frac: 0.8,
            enter_normal_offset: 0.1,
            min_speed: 0.2,
            mode_wait: 0.5,
            stopped_speed: 0.1,
            front_side_margin: 0.05,
            front_blocked: 0.1,
            front_clear: 0.2,
            backup_speed: 0.1,
            backup_min_time: 1.0,
            backup_max_time: 2.0,
            rotate_min_w: 0.5,
            rotate_max_w: 1.0,
            rotate_tolerance: 0.2,
            recovery_successes: 5,
            recovery_max_level: 4,
            low_creep_v: 0.2,
            recovery_creep_v: 0.05,
            recovery_turn_v: 0.02,
            recovery_turn_w: 0.5,
            normal_goal: 0.9,
            normal_obstacle: 0.3,
            normal_heading: 0.2,
            normal_space: 0.0,
            low_goal: 0.8,
            low_obstacle: 0.2,
            low_heading: 0.1,
            low_space: 0.2,
            normal_margin: 0.05,
            low_margin: 0.01,
            normal_min_travel: 0.3,
            low_min_travel: 0.1,
            recovery_min_travel: 0.02,
            low_goal_offset: 0.25,
            low_min_safe_time: 0.5,
            clearance_cap: 0.3,
            space_cap: 2.0,
            space_half_angle_deg: 45.0,
            verify_time: 0.5,
            moving_hold_time: 1.0,
            map_resolution: 0.05,
        }
    }
}
