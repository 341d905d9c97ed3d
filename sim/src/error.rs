//! A simulator configuration value that cannot work ([`ConfigError`]: `settings::ConfigError`,
//! re-exported, since the robot's `[dynamics]` settings it also reports on are plain settings).

pub use settings::ConfigError;
