//! The simulator: BARN and DynaBARN worlds (static and moving obstacles), Jackal kinematics and its true response to commands (lag,
//! acceleration limits, skid-steer slip, latency, localization drift: [`dynamics`]), a 2-D
//! lidar, exact footprint collision, the robot's own costmap and global path, episodes with
//! the BARN protocol, and the score.
//!
//! Pure and deterministic: every random draw comes from a seed the caller passes in.

pub mod barn;
pub mod catalog;
pub mod costmap;
pub mod dynabarn;
pub mod dynamics;
pub mod episode;
mod error;
pub mod fan;
pub mod generate;
pub mod geometry;
pub mod grid;
pub mod lidar;
pub mod metrics;
pub mod motion;
pub mod nav_stack;
pub mod navigation;
pub mod predictive_cost;
pub mod robot;
pub mod score;
pub mod splits;
pub mod world;

pub use dynamics::{Dynamics, Profile};
pub use episode::{Episode, EpisodeConfig, EpisodeResult, Perception, Status};
pub use error::ConfigError;
pub use geometry::{Circle, Footprint, Pose, Vec2};
pub use robot::{RobotLimits, RobotState, Twist};
pub use world::{Scene, World};
