#![warn(missing_docs)]
//! The evaluation configuration (`configs/eval.toml`, embedded as the default;
//! [`EvalConfig`]) and the one-line form of a parser's message ([`one_line`]).
//!
//! `adp eval` and its kin (the `adp-eval` crate) and the robot runtime (`adp-runtime`, its
//! `settings` file) read it; this crate links neither evaluation nor a learner.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use planner::{
    ComputeConfig, DwaConfig, LogMppiConfig, MppiConfig, PadpConfig, PlannerConfigs, SystemConfig,
};
use sim::EpisodeConfig;

/// The embedded default.
pub const EVAL_TOML: &str = include_str!("../../configs/eval.toml");

/// Settings for `adp eval` and friends.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalConfig {
    /// Simulator and protocol.
    pub episode: EpisodeConfig,
    /// DWA planner.
    pub dwa: DwaConfig,
    /// MPPI planner.
    pub mppi: MppiConfig,
    /// Log-MPPI planner.
    pub log_mppi: LogMppiConfig,
    /// The standalone navigation system.
    pub system: SystemConfig,
    /// The onboard compute model every planner runs under (`[compute]`).
    pub compute: ComputeConfig,
    /// PADP's settings for the rows of `--prediction padp-path` and `padp` (`[prediction]`).
    pub prediction: PadpConfig,
}

impl EvalConfig {
    /// Every planner's tunables, for [`planner::PlannerKind::build`].
    pub fn planners(&self) -> PlannerConfigs {
        PlannerConfigs {
            dwa: self.dwa,
            mppi: self.mppi,
            log_mppi: self.log_mppi,
            system: self.system,
        }
    }

    /// Reads `path`, or the embedded default when `None`; a [`ConfigError::Read`] or a
    /// [`ConfigError::Invalid`] naming the file and the key.
    pub fn load(path: Option<&Path>) -> Result<Self, ConfigError> {
        let (name, text) = match path {
            Some(p) => (
                p.display().to_string(),
                std::fs::read_to_string(p).map_err(|source| ConfigError::Read {
                    path: p.to_path_buf(),
                    source,
                })?,
            ),
            None => ("configs/eval.toml (embedded)".to_string(), EVAL_TOML.to_string()),
        };
        let config_error = |message: String| ConfigError::Invalid {
            origin: name.clone(),
            message,
        };
        let cfg: EvalConfig = toml::from_str(&text).map_err(|e| config_error(one_line(&e.to_string())))?;
        cfg.episode
            .validate()
            .map_err(|e| config_error(format!("[episode] {e}")))?;
        cfg.compute.validate().map_err(|e| config_error(e.to_string()))?;
        cfg.prediction
            .validate()
            .map_err(|e| config_error(e.to_string()))?;
        Ok(cfg)
    }
}

/// Why [`EvalConfig::load`] failed; one line naming the file (and the key).
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file holds a value that cannot be used.
    #[error("{origin}: {message}")]
    Invalid {
        /// The file (or the embedded default).
        origin: String,
        /// What is wrong, naming the key.
        message: String,
    },
}

/// Collapses a multi-line parser message (toml prints a snippet) into one line.
pub fn one_line(s: &str) -> String {
    s.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('|') && !l.chars().all(|c| c == '^' || c == ' '))
        .collect::<Vec<_>>()
        .join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_config_equals_built_in_defaults() {
        let cfg = EvalConfig::load(None).unwrap();
        assert_eq!(cfg.episode, EpisodeConfig::default());
        assert_eq!(cfg.dwa, DwaConfig::default());
        assert_eq!(cfg.mppi, MppiConfig::default());
        assert_eq!(cfg.log_mppi, LogMppiConfig::default());
        assert_eq!(cfg.system, SystemConfig::default());
    }

    #[test]
    fn unknown_field_is_named() {
        let dir = std::env::temp_dir().join(format!("adp-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("bad.toml");
        std::fs::write(&p, "[dwa]\nv_sampels = 3\n").unwrap();
        let e = EvalConfig::load(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("v_sampels") && !e.contains('\n'), "{e}");
        std::fs::write(&p, "[episode]\nphysics_dt = 0.5\n").unwrap();
        let e = EvalConfig::load(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("physics_dt"), "{e}");
    }
}
