#![warn(missing_docs)]
//! The layout actors and the learner share: the observation vector ([`observation`], with the
//! laser segment's [`laser::LaserLayout`]) and the size of the policy's flat weight vector
//! ([`weights::param_count`]).
//!
//! This crate is the one definition: the actor builds its observations in this layout, the
//! learner sizes its networks with [`obs_dim`] and checks them against the run's settings, and
//! the exported policy card documents [`segments`] with [`Segment::encoding`]. It depends on
//! nothing of either side.

pub mod laser;
pub mod observation;
pub mod weights;

pub use laser::{LaserLayout, LayoutError, LASER_BEAMS, LASER_FIELD_DEG, MAX_SECTORS};
pub use observation::{
    obs_dim, segments, Segment, DEFAULT_LASER_CLIP_M, MAX_OBSERVED_TRACKS, SEGMENT_NAMES, STATE_TAIL,
    TRACK_FLOATS,
};
pub use weights::param_count;
