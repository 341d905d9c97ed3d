//! PADP's complexity indicator and its hysteresis mode switch (Eqs. 7-8 of the PADP paper).
//!
//! The score `Phi = l1 rho + l2 beta + l3 H` (Eq. 7) combines three nondimensional terms in
//! [0, 1]: `rho`, the density of moving obstacles within sensing range (moving tracks within
//! [`ComplexityConfig::range`], over [`ComplexityConfig::dense_count`], capped at 1); `beta`,
//! the blocked share of the global path's next [`ComplexityConfig::ahead`] metres; and `H`,
//! the entropy of the local costs over `B` bins, divided by `ln B` (the paper's `H_k` in
//! nats, normalised so that a uniform spread scores 1). The paper reads the sum as a
//! coordination score, not a definition of complexity; so do we. `crate::padp` measures
//! the three terms on the robot's own map, path and tracks.
//!
//! The mode (Eq. 8) moves between A (low pressure: plan for efficiency), B (balanced) and C
//! (high pressure: weight local risk) with thresholds `theta_L < theta_H` and a hysteresis
//! width `delta`: up from A when `Phi > theta_L + delta` (to C at once when
//! `Phi > theta_H + delta`), up from B when `Phi > theta_H + delta`, down from C when
//! `Phi < theta_H - delta` (to A at once when `Phi < theta_L - delta`), down from B when
//! `Phi < theta_L - delta`. The paper's values are the defaults: `l = [0.38, 0.37, 0.25]`,
//! `[theta_L, theta_H] = [0.38, 0.64]`, `delta = 0.05`.
//!
//! What a mode changes ([`ModeEffects`]): the paper's mode A has "a longer global replanning
//! interval and a stronger preference for efficiency", mode C "shortens the replanning
//! interval and increases the weight of local risk constraints", B balances them; its
//! replanning intervals are 12 / 5 / 2 steps (and its local rollout horizons 4 / 6 / 7
//! steps, which we leave to the schedule: choosing the horizon is the fidelity strategy's
//! job, DDP's or an ADP policy's). Here B is the configured planner (every gain factor 1,
//! `[episode] replan_every`); A and C scale the planner's efficiency gains (goal progress,
//! speed) and risk gains (obstacle clearance, the forecast's included) by the factors of
//! [`ModeEffects`], and the replanning interval by 12/5 and 2/5.
//!
//! Pure functions and a two-word state; no allocation.

use serde::{Deserialize, Serialize};

/// Parameters of the score and the switch. Every field is optional in a TOML table; unknown
/// keys are refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ComplexityConfig {
    /// Weights `[l1, l2, l3]` of density, blockage and entropy.
    pub weights: [f64; 3],
    /// Moving obstacles in sensing range that make the density term 1.
    pub dense_count: f64,
    /// Sensing range of the density and entropy terms (m): the robot's mapping range.
    pub range: f64,
    /// Length of the global path ahead whose blocked share is `beta` (m).
    pub ahead: f64,
    /// Cost bins `B` of the entropy term (at least 2).
    pub bins: usize,
    /// Lower threshold `theta_L`.
    pub low: f64,
    /// Upper threshold `theta_H`.
    pub high: f64,
    /// Hysteresis width `delta`.
    pub hysteresis: f64,
}

impl Default for ComplexityConfig {
    fn default() -> Self {
        Self {
            weights: [0.38, 0.37, 0.25],
            dense_count: 5.0,
            range: 6.0,
            ahead: 3.0,
            bins: 8,
            low: 0.38,
            high: 0.64,
            hysteresis: 0.05,
        }
    }
}

/// A complexity setting that cannot work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("[complexity] {key}: {why}")]
pub struct ComplexityConfigError {
    /// The key.
    pub key: &'static str,
    /// What is wrong.
    pub why: String,
}

impl ComplexityConfig {
    /// Checks every field; the error names the key.
    pub fn validate(&self) -> Result<(), ComplexityConfigError> {
        let bad = |key, why: String| Err(ComplexityConfigError { key, why });
        if self.weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return bad(
                "weights",
                format!("{:?}: each must be finite and >= 0", self.weights),
            );
        }
        if !(self.dense_count.is_finite() && self.dense_count > 0.0) {
            return bad(
                "dense_count",
                format!("{}: must be finite and > 0", self.dense_count),
            );
        }
        for (key, value) in [("range", self.range), ("ahead", self.ahead)] {
            if !(value.is_finite() && value > 0.0) {
                return bad(key, format!("{value}: must be finite and > 0"));
            }
        }
        if self.bins < 2 {
            return bad("bins", format!("{}: must be at least 2", self.bins));
        }
        if !(self.hysteresis.is_finite() && self.hysteresis >= 0.0) {
            return bad(
                "hysteresis",
                format!("{}: must be finite and >= 0", self.hysteresis),
            );
        }
        if !(self.low.is_finite()
            && self.high.is_finite()
            && self.low + self.hysteresis < self.high - self.hysteresis)
        {
            return bad(
                "low",
                format!(
                    "low {} + hysteresis {} must be below high {} - hysteresis",
                    self.low, self.hysteresis, self.high
                ),
            );
        }
        Ok(())
    }

    /// `Phi` (Eq. 7) of `moving` obstacles in range, the `blocked` share of the path ahead
    /// and the normalized `entropy` of the local costs (see [`entropy`]; both in [0, 1]).
    pub fn score(&self, moving: usize, blocked: f64, entropy: f64) -> f64 {
        let rho = (moving as f64 / self.dense_count).min(1.0);
        let beta = blocked.clamp(0.0, 1.0);
        let h = entropy.clamp(0.0, 1.0);
        self.weights[0] * rho + self.weights[1] * beta + self.weights[2] * h
    }
}

/// Entropy of `costs` (each clamped to [0, 1]) over `bins` equal bins, divided by `ln bins`:
/// 0 when every cost falls in one bin, 1 when they spread evenly. Empty input gives 0.
pub fn entropy(costs: &[f64], bins: usize) -> f64 {
    const MAX_BINS: usize = 64;
    let bins = bins.clamp(2, MAX_BINS);
    if costs.is_empty() {
        return 0.0;
    }
    let mut counts = [0u32; MAX_BINS];
    for &c in costs {
        let b = ((c.clamp(0.0, 1.0) * bins as f64) as usize).min(bins - 1);
        counts[b] += 1;
    }
    let n = costs.len() as f64;
    let h: f64 = counts[..bins]
        .iter()
        .filter(|&&k| k > 0)
        .map(|&k| {
            let p = f64::from(k) / n;
            -p * p.ln()
        })
        .sum();
    h / (bins as f64).ln()
}

/// PADP's planning modes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum PressureMode {
    /// Low pressure: longer replanning interval, efficiency first.
    #[default]
    A,
    /// Balanced.
    B,
    /// High pressure: shorter replanning interval, local risk weighted up.
    C,
}

impl PressureMode {
    /// Every mode, in the order of [`PressureMode::index`].
    pub const ALL: [PressureMode; 3] = [PressureMode::A, PressureMode::B, PressureMode::C];

    /// 0 for A, 1 for B, 2 for C: the index of the mode's entry in [`ModeEffects`].
    pub fn index(self) -> usize {
        match self {
            PressureMode::A => 0,
            PressureMode::B => 1,
            PressureMode::C => 2,
        }
    }
}

/// What each mode changes: factors on the planner's gains by their role, and on the global
/// replanning interval; one entry per mode, A, B, C. Every field is optional in a TOML table;
/// unknown keys are refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModeEffects {
    /// Factor on the efficiency gains (goal progress, speed) in modes A, B, C.
    pub efficiency: [f64; 3],
    /// Factor on the local-risk gains (obstacle clearance) in modes A, B, C.
    pub risk: [f64; 3],
    /// Global replanning interval in modes A, B, C, as a multiple of `[episode]
    /// replan_every` (rounded, at least one period).
    pub replan_scale: [f64; 3],
}

impl Default for ModeEffects {
    /// B is the configured planner; A leans to efficiency, C to risk (our factors: the paper
    /// gives none); the replanning intervals keep the paper's 12 : 5 : 2.
    fn default() -> Self {
        Self {
            efficiency: [1.25, 1.0, 0.8],
            risk: [0.8, 1.0, 1.5],
            replan_scale: [2.4, 1.0, 0.4],
        }
    }
}

impl ModeEffects {
    /// Checks every factor; the error names the key.
    pub fn validate(&self) -> Result<(), ComplexityConfigError> {
        for (key, values, zero_ok) in [
            ("efficiency", self.efficiency, true),
            ("risk", self.risk, true),
            ("replan_scale", self.replan_scale, false),
        ] {
            if values
                .iter()
                .any(|v| !(v.is_finite() && (*v > 0.0 || (zero_ok && *v == 0.0))))
            {
                let need = if zero_ok { ">= 0" } else { "> 0" };
                return Err(ComplexityConfigError {
                    key,
                    why: format!("{values:?}: each must be finite and {need}"),
                });
            }
        }
        Ok(())
    }

    /// The replanning interval of `mode` for a configured interval of `periods`.
    pub fn replan_every(&self, mode: PressureMode, periods: u32) -> u32 {
        ((periods as f64 * self.replan_scale[mode.index()]).round() as u32).max(1)
    }
}

/// The hysteresis switch of Eq. 8: the mode, updated with each score.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ModeSwitch {
    mode: PressureMode,
}

impl ModeSwitch {
    /// The current mode.
    pub fn mode(&self) -> PressureMode {
        self.mode
    }

    /// Takes the score `phi` and returns the new mode.
    pub fn update(&mut self, phi: f64, cfg: &ComplexityConfig) -> PressureMode {
        let (lo, hi, d) = (cfg.low, cfg.high, cfg.hysteresis);
        self.mode = match self.mode {
            PressureMode::A if phi > hi + d => PressureMode::C,
            PressureMode::A if phi > lo + d => PressureMode::B,
            PressureMode::B if phi > hi + d => PressureMode::C,
            PressureMode::B if phi < lo - d => PressureMode::A,
            PressureMode::C if phi < lo - d => PressureMode::A,
            PressureMode::C if phi < hi - d => PressureMode::B,
            m => m,
        };
        self.mode
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entropy_by_hand() {
        // Four costs in two of four bins, two each: -2 (1/2 ln 1/2) / ln 4 = 0.5.
        assert!((entropy(&[0.1, 0.2, 0.9, 0.95], 4) - 0.5).abs() < 1e-12);
        assert_eq!(entropy(&[0.3, 0.3, 0.3], 4), 0.0);
        assert!((entropy(&[0.1, 0.3, 0.6, 0.9], 4) - 1.0).abs() < 1e-12);
        assert_eq!(entropy(&[], 4), 0.0);
        // Out-of-range costs land in the end bins.
        assert_eq!(entropy(&[-3.0, 0.0, 1.0, 7.0], 2), 1.0);
    }

    #[test]
    fn the_score_weights_its_three_terms() {
        let cfg = ComplexityConfig::default();
        // 2 of 5 moving obstacles, 50 % blocked, and costs in two of 8 bins, two each:
        // entropy ln 2 / ln 8 = 1/3.
        let h = entropy(&[0.05, 0.05, 0.95, 0.95], cfg.bins);
        let phi = cfg.score(2, 0.5, h);
        let want = 0.38 * 0.4 + 0.37 * 0.5 + 0.25 / 3.0;
        assert!((phi - want).abs() < 1e-12, "{phi} vs {want}");
        // Density and blockage saturate at 1.
        assert!((cfg.score(50, 3.0, 0.0) - 0.75).abs() < 1e-12);
    }

    #[test]
    fn the_switch_holds_inside_the_hysteresis_band() {
        let cfg = ComplexityConfig::default();
        let mut s = ModeSwitch::default();
        // Up through the thresholds: only past theta + delta.
        assert_eq!(s.update(0.42, &cfg), PressureMode::A);
        assert_eq!(s.update(0.44, &cfg), PressureMode::B);
        assert_eq!(s.update(0.68, &cfg), PressureMode::B);
        assert_eq!(s.update(0.70, &cfg), PressureMode::C);
        // Down: only below theta - delta.
        assert_eq!(s.update(0.60, &cfg), PressureMode::C);
        assert_eq!(s.update(0.58, &cfg), PressureMode::B);
        assert_eq!(s.update(0.34, &cfg), PressureMode::B);
        assert_eq!(s.update(0.32, &cfg), PressureMode::A);
        // Jumps skip the middle mode.
        assert_eq!(s.update(0.9, &cfg), PressureMode::C);
        assert_eq!(s.update(0.1, &cfg), PressureMode::A);
    }

    #[test]
    fn the_modes_scale_the_replanning_interval_as_the_paper_does() {
        let fx = ModeEffects::default();
        let every: Vec<u32> = PressureMode::ALL.iter().map(|&m| fx.replan_every(m, 5)).collect();
        assert_eq!(every, [12, 5, 2]);
        assert_eq!(fx.replan_every(PressureMode::C, 1), 1, "at least one period");
        fx.validate().unwrap();
        let bad = ModeEffects {
            replan_scale: [1.0, 0.0, 1.0],
            ..fx
        };
        assert_eq!(bad.validate().unwrap_err().key, "replan_scale");
        let bad = ModeEffects {
            risk: [1.0, f64::NAN, 1.0],
            ..fx
        };
        assert!(bad.validate().unwrap_err().to_string().contains("risk"));
    }

    #[test]
    fn bad_settings_are_named() {
        let bad = ComplexityConfig {
            range: 0.0,
            ..ComplexityConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().key, "range");
        let bad = ComplexityConfig {
            low: 0.6,
            high: 0.62,
            ..ComplexityConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().key, "low");
        let bad = ComplexityConfig {
            bins: 1,
            ..ComplexityConfig::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("bins"));
        ComplexityConfig::default().validate().unwrap();
    }
}
