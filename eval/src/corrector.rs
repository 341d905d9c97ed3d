//! The residual corrector that `adp eval --prediction kf-res` uses: the file `[prediction]
//! residual` names, or the one embedded from `assets/kf-residual/` (made by `adp tracks`, see
//! its README).

use std::path::Path;
use std::sync::Arc;

use planner::residual::Corrector;

use crate::error::{Error, Result};

/// The corrector trained on `dynabarn-fit` that `--prediction kf-res` uses when the
/// configuration names none (`assets/kf-residual/README.md` says how it was made).
pub const DEFAULT_CORRECTOR: &str = include_str!("../../assets/kf-residual/corrector.json");

/// The embedded corrector's name in errors.
pub const DEFAULT_CORRECTOR_NAME: &str = "assets/kf-residual/corrector.json (embedded)";

/// The corrector at `path`, or the embedded default.
pub fn load_corrector(path: Option<&Path>) -> Result<Arc<Corrector>> {
    let c = match path {
        Some(p) => Corrector::load(p),
        None => Corrector::from_json(DEFAULT_CORRECTOR, DEFAULT_CORRECTOR_NAME),
    };
    c.map(Arc::new)
        .map_err(|e| Error::component("the residual corrector", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_corrector_loads() {
        let c = load_corrector(None).unwrap();
        assert_eq!(c.net().sizes(), vec![13, 64, 64, 14]);
        assert_eq!(
            (c.gain, c.threshold_rad, c.clip_m),
            (
                planner::residual::PAPER_GAIN,
                planner::residual::PAPER_THRESHOLD_RAD,
                planner::residual::PAPER_CLIP_M
            )
        );
        // Trained on dynabarn-fit only.
        let fit = sim::splits::select("dynabarn-fit").unwrap();
        let t = &c.trained;
        assert!(t
            .train_worlds
            .iter()
            .chain(&t.val_worlds)
            .all(|w| fit.contains(w)));
    }
}
