//! The evaluation configuration ([`EvalConfig`], `configs/eval.toml`) and the one-line form of
//! a parser's message ([`one_line`]): the `adp-eval-config` crate's, which the robot runtime
//! shares without linking evaluation; and [`UnknownName`], the command line's error for a
//! name it does not know.

pub use eval_config::{one_line, ConfigError, EvalConfig, EVAL_TOML};

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
