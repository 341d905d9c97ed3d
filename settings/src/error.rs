//! A simulator configuration value that cannot work ([`ConfigError`]): a value of the
//! robot's [`crate::dynamics`], or of the simulator's own episode and lidar settings.

/// A configuration value that cannot work; the message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// A value outside its range (`rule` says the range, e.g. `must be in (0, 0.01]`).
    #[error("{field} = {value} {rule}")]
    Value {
        /// The field.
        field: &'static str,
        /// Its value.
        value: f64,
        /// What it must satisfy.
        rule: String,
    },
    /// `replan_every` is 0.
    #[error("replan_every must be >= 1")]
    ReplanEvery,
    /// The lidar's range limits are out of order.
    #[error("lidar ranges [{min}, {max}] must satisfy 0 <= min_range < max_range")]
    LidarRanges {
        /// `min_range`.
        min: f64,
        /// `max_range`.
        max: f64,
    },
    /// `profile = "custom"` without its dynamics table.
    #[error("profile = \"custom\" needs a complete [{table}] table (see configs/eval.toml)")]
    MissingTable {
        /// The table, e.g. `episode.dynamics`.
        table: String,
    },
    /// A dynamics table with a preset profile.
    #[error("[{table}] is given with profile = \"{profile}\"; set profile = \"custom\" to use it")]
    StrayTable {
        /// The table.
        table: String,
        /// The preset profile's name.
        profile: &'static str,
    },
    /// A value of a custom dynamics table.
    #[error("[{table}] {source}")]
    Table {
        /// The table.
        table: String,
        /// What is wrong in it.
        source: Box<ConfigError>,
    },
}

impl ConfigError {
    /// A [`ConfigError::Value`] (`rule` says what `field` must satisfy).
    pub fn value(field: &'static str, value: f64, rule: impl Into<String>) -> Self {
        Self::Value {
            field,
            value,
            rule: rule.into(),
        }
    }
}
