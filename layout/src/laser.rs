//! The observation's laser segment layout (`[env] observation`): the 720-range scan or the
//! least range per angular sector.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Lidar beams in the `scan` layout (the Hokuyo UST-10's 720 over 270 degrees).
pub const LASER_BEAMS: usize = 720;
/// The angular field every laser layout covers (degrees), centred on the heading.
pub const LASER_FIELD_DEG: f64 = 270.0;
/// Most sectors of a `sectors:N` layout (one per beam of the `scan` layout).
pub const MAX_SECTORS: usize = LASER_BEAMS;

/// How the observation's laser segment is laid out (`[env] observation`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum LaserLayout {
    /// `"scan"` (the default): [`LASER_BEAMS`] ranges in beam order, beam k at `-135 + k *
    /// 270/719` degrees from the heading.
    #[default]
    Scan,
    /// `"sectors:N"`: the 270-degree field split into `N` equal sectors (1 to
    /// [`MAX_SECTORS`]), from -135 degrees counter-clockwise; each value is the least range
    /// the lidar measured in its sector (the N nearest-obstacle distances of the 3D RL-DWA
    /// paper's sensing resolutions, 15, 25 and 50).
    Sectors(usize),
}

impl LaserLayout {
    /// Floats of the laser segment: [`LASER_BEAMS`] or `N`.
    pub fn size(self) -> usize {
        match self {
            LaserLayout::Scan => LASER_BEAMS,
            LaserLayout::Sectors(n) => n,
        }
    }
}

impl fmt::Display for LaserLayout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LaserLayout::Scan => f.write_str("scan"),
            LaserLayout::Sectors(n) => write!(f, "sectors:{n}"),
        }
    }
}

/// Why a laser layout name was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("observation = {0:?} is not a laser layout: \"scan\" or \"sectors:N\" with N in 1..={MAX_SECTORS}")]
pub struct LayoutError(pub String);

impl FromStr for LaserLayout {
    type Err = LayoutError;

    fn from_str(s: &str) -> Result<Self, LayoutError> {
        if s == "scan" {
            return Ok(LaserLayout::Scan);
        }
        s.strip_prefix("sectors:")
            .and_then(|n| n.parse::<usize>().ok())
            .filter(|n| (1..=MAX_SECTORS).contains(n))
            .map(LaserLayout::Sectors)
            .ok_or_else(|| LayoutError(s.to_string()))
    }
}

impl TryFrom<String> for LaserLayout {
    type Error = LayoutError;

    fn try_from(s: String) -> Result<Self, LayoutError> {
        s.parse()
    }
}

impl From<LaserLayout> for String {
    fn from(l: LaserLayout) -> String {
        l.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_parse_and_print() {
        for (text, layout) in [
            ("scan", LaserLayout::Scan),
            ("sectors:15", LaserLayout::Sectors(15)),
            ("sectors:720", LaserLayout::Sectors(720)),
        ] {
            assert_eq!(text.parse::<LaserLayout>().unwrap(), layout);
            assert_eq!(layout.to_string(), text);
        }
        for bad in ["sectors:0", "sectors:721", "sectors:", "sectors:x", "beams", ""] {
            let e = bad.parse::<LaserLayout>().unwrap_err().to_string();
            assert_eq!(
                e,
                format!(
                    "observation = {bad:?} is not a laser layout: \"scan\" or \"sectors:N\" with N in 1..=720"
                )
            );
        }
        assert_eq!(LaserLayout::default().size(), 720);
        assert_eq!(LaserLayout::Sectors(50).size(), 50);
    }
}
