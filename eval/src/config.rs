//! The evaluation configuration (`configs/eval.toml`, embedded as the default;
//! [`EvalConfig`]) and the one-line form of a parser's message.

use serde::Deserialize;

use crate::error::{Error, Result};

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

    /// Reads `path`, or the embedded default when `None`; an [`Error::Io`] or an
    /// [`Error::Config`] naming the file and the key.
    pub fn load(path: Option<&std::path::Path>) -> Result<Self> {
        let (name, text) = match path {
            Some(p) => (
                p.display().to_string(),
                std::fs::read_to_string(p).map_err(|e| Error::io("read config", p, e))?,
            ),
            None => ("configs/eval.toml (embedded)".to_string(), EVAL_TOML.to_string()),
        };
        let config_error = |message: String| Error::Config {
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

/// A name that is none of the known ones (a planner, a simulator profile).
#[derive(Debug, thiserror::Error)]
#[error("unknown {kind} `{name}` (expected {expected})")]
pub struct UnknownName {
    /// What the name should name, e.g. `planner`.
    pub kind: &'static str,
    /// The name given.
    pub name: String,
    /// The known names, e.g. `dwa, mppi, log-mppi or system`.
    pub expected: &'static str,
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
