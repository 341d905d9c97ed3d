//! The run's settings on the wire: the conversions of `proto::spec` (planner, action space
//! and environment settings to and from their `adp.v1` messages), re-exported here where the
//! actor reads its run spec. A decoded [`crate::EnvConfig`] has passed
//! [`crate::EnvConfig::validate`].

pub use proto::spec::*;
