//! PADP's predictive dynamic cost field (Eqs. 4-5 of the PADP paper): an anisotropic risk
//! kernel around each moving obstacle's predicted positions, long along its motion and
//! narrow across it, weaker the further ahead in time.
//!
//! For obstacle `i` predicted at steps `tau = 1..=N_p` (constant velocity, `step_s` apart),
//! a point `p` is expressed in the frame of the obstacle's motion (Eq. 4):
//! `[dx, dy] = R(-psi_i) (p - o_i(tau))`, and the field is (Eq. 5)
//!
//! `J_dyn(p) = sum_i sum_tau gamma^tau exp(-dx^2 / (2 s_par(tau)^2) - dy^2 / (2 s_perp(tau)^2))`.
//!
//! The paper sets `N_p = 7`, `gamma = 0.80`, `s_par = 1.60` and `s_perp = 1.00` grid cells
//! for a robot of radius 0.90 cells, and says only that both scales grow with `tau`, the
//! longitudinal one faster. Here the scales are in metres, taken as the paper's ratio to its
//! robot radius times the Jackal's circumscribed radius (0.333 m): `s_par = 1.60 / 0.90 x
//! 0.333 = 0.59 m`, `s_perp = 0.37 m`; they grow linearly, `s(tau) = s (1 + g tau / N_p)`,
//! with `g_par = 1.0` and `g_perp = 0.5` (our choice, documented as such). The paper's step
//! is its simulation step, 0.40 s; ours is the same 0.40 s, so 7 steps look 2.8 s ahead.
//!
//! A stationary obstacle (speed below [`PredictiveCostConfig::min_speed`]) has no direction
//! of motion and no future to predict: it contributes nothing (it is in the static costmap).
//! Pure functions of plain data; no allocation.
//!
//! [`add_to_grid`] lays the field over a grid of cells, as the global path search weighs it
//! (`crate::navigation::GlobalPlanner::plan_among`, PADP Eq. 6): each kernel is cut off
//! where it falls below 1.1 % of its peak, so a field over a whole costmap costs a few
//! thousand kernel evaluations per obstacle and step.

use serde::{Deserialize, Serialize};

use crate::geometry::Vec2;

/// Parameters of the predictive field. Every field is optional in a TOML table; unknown keys
/// are refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictiveCostConfig {
    /// Prediction steps `N_p`.
    pub steps: usize,
    /// Time between prediction steps (s).
    pub step_s: f64,
    /// Temporal decay `gamma` per step.
    pub gamma: f64,
    /// Longitudinal scale at `tau = 0` (m).
    pub sigma_par: f64,
    /// Lateral scale at `tau = 0` (m).
    pub sigma_perp: f64,
    /// Relative growth of the longitudinal scale over the `N_p` steps.
    pub growth_par: f64,
    /// Relative growth of the lateral scale over the `N_p` steps.
    pub growth_perp: f64,
    /// Obstacles slower than this (m/s) are treated as static and add nothing.
    pub min_speed: f64,
}

impl Default for PredictiveCostConfig {
    fn default() -> Self {
        Self {
            steps: 7,
            step_s: 0.40,
            gamma: 0.80,
            sigma_par: 0.59,
            sigma_perp: 0.37,
            growth_par: 1.0,
            growth_perp: 0.5,
            min_speed: 0.05,
        }
    }
}

/// A predictive-field setting that cannot work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("[predictive_cost] {key} = {value}: {why}")]
pub struct PredictiveCostError {
    /// The key.
    pub key: &'static str,
    /// Its value.
    pub value: f64,
    /// What is wrong.
    pub why: &'static str,
}

impl PredictiveCostConfig {
    /// Checks every field; the error names the key.
    pub fn validate(&self) -> Result<(), PredictiveCostError> {
        let bad = |key, value, why| Err(PredictiveCostError { key, value, why });
        if self.steps == 0 {
            return bad("steps", 0.0, "must be at least 1");
        }
        for (key, value) in [
            ("step_s", self.step_s),
            ("sigma_par", self.sigma_par),
            ("sigma_perp", self.sigma_perp),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return bad(key, value, "must be finite and > 0");
            }
        }
        if !(self.gamma > 0.0 && self.gamma <= 1.0) {
            return bad("gamma", self.gamma, "must be in (0, 1]");
        }
        for (key, value) in [
            ("growth_par", self.growth_par),
            ("growth_perp", self.growth_perp),
            ("min_speed", self.min_speed),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return bad(key, value, "must be finite and >= 0");
            }
        }
        Ok(())
    }

    /// The largest value one obstacle can contribute: `sum_tau gamma^tau`.
    pub fn peak(&self) -> f64 {
        (1..=self.steps).map(|t| self.gamma.powi(t as i32)).sum()
    }
}

/// A moving obstacle as the field sees it: where it is now and how fast it moves.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MovingObstacle {
    /// Centre now (m).
    pub position: Vec2,
    /// Velocity (m/s).
    pub velocity: Vec2,
}

/// One term of Eq. 5: the kernel of one obstacle at one prediction step.
#[derive(Clone, Copy, Debug)]
struct Kernel {
    /// The predicted centre `o_i(tau)`.
    centre: Vec2,
    /// `cos psi_i`, `sin psi_i`: the direction of motion.
    cos: f64,
    sin: f64,
    /// `2 s_par(tau)^2` and `2 s_perp(tau)^2`.
    two_par2: f64,
    two_perp2: f64,
    /// The larger of the two scales (m), for bounding the kernel.
    reach: f64,
    /// `gamma^tau`.
    weight: f64,
}

impl Kernel {
    /// The kernel's exponent at `p` (Eq. 4 then the exponent of Eq. 5; at most 0).
    #[inline]
    fn exponent(&self, p: Vec2) -> f64 {
        let d = p - self.centre;
        let dx = self.cos * d.x + self.sin * d.y;
        let dy = -self.sin * d.x + self.cos * d.y;
        -(dx * dx) / self.two_par2 - (dy * dy) / self.two_perp2
    }
}

/// The kernels of Eq. 5 of every moving obstacle, step after step.
fn kernels<'a>(
    obstacles: &'a [MovingObstacle],
    cfg: &'a PredictiveCostConfig,
) -> impl Iterator<Item = Kernel> + 'a {
    obstacles
        .iter()
        .filter(move |o| o.velocity.norm() >= cfg.min_speed)
        .flat_map(move |o| {
            let speed = o.velocity.norm();
            // R(-psi) with cos psi = vx / |v|, sin psi = vy / |v|.
            let (cos, sin) = (o.velocity.x / speed, o.velocity.y / speed);
            let mut weight = 1.0;
            (1..=cfg.steps).map(move |tau| {
                weight *= cfg.gamma;
                let t = tau as f64;
                let grow = t / cfg.steps as f64;
                let s_par = cfg.sigma_par * (1.0 + cfg.growth_par * grow);
                let s_perp = cfg.sigma_perp * (1.0 + cfg.growth_perp * grow);
                Kernel {
                    centre: o.position + o.velocity * (t * cfg.step_s),
                    cos,
                    sin,
                    two_par2: 2.0 * s_par * s_par,
                    two_perp2: 2.0 * s_perp * s_perp,
                    reach: s_par.max(s_perp),
                    weight,
                }
            })
        })
}

/// `J_dyn(p)` of Eq. 5 over `obstacles`.
pub fn predictive_cost(p: Vec2, obstacles: &[MovingObstacle], cfg: &PredictiveCostConfig) -> f64 {
    kernels(obstacles, cfg)
        .map(|k| k.weight * k.exponent(p).exp())
        .sum()
}

/// Where [`add_to_grid`] cuts each kernel off: beyond this many of its scales (an ellipse),
/// where the kernel is below `exp(-3^2 / 2)`, 1.1 % of its peak.
pub const GRID_CUTOFF_SIGMAS: f64 = 3.0;

/// A regular grid of cells, row after row (`x` fastest): cell `(ix, iy)` is centred at
/// `first + resolution (ix, iy)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Centre of cell (0, 0) (m).
    pub first: Vec2,
    /// Cell size (m).
    pub resolution: f64,
    /// Cells along x.
    pub nx: usize,
    /// Cells along y.
    pub ny: usize,
}

/// Adds `scale x J_dyn` (Eq. 5) at every cell centre of `grid` into `out` (`nx x ny` values,
/// row after row), each kernel cut off beyond [`GRID_CUTOFF_SIGMAS`] of its scales, so only
/// the cells near a predicted position are visited. Returns the number of kernel evaluations.
///
/// # Panics
/// If `out` is shorter than the grid.
pub fn add_to_grid(
    obstacles: &[MovingObstacle],
    cfg: &PredictiveCostConfig,
    grid: &Grid,
    scale: f64,
    out: &mut [f32],
) -> u64 {
    assert!(
        out.len() >= grid.nx * grid.ny,
        "predictive cost grid: {} values for {} x {} cells",
        out.len(),
        grid.nx,
        grid.ny
    );
    let cutoff = -0.5 * GRID_CUTOFF_SIGMAS * GRID_CUTOFF_SIGMAS;
    let mut evaluations = 0;
    for k in kernels(obstacles, cfg) {
        // The cells whose centres lie within the cutoff's bounding square.
        let r = GRID_CUTOFF_SIGMAS * k.reach;
        let range = |lo: f64, hi: f64, first: f64, n: usize| {
            let a = ((lo - first) / grid.resolution).ceil().max(0.0);
            let b = ((hi - first) / grid.resolution).floor().min(n as f64 - 1.0);
            (a <= b).then_some((a as usize, b as usize))
        };
        let (Some((x0, x1)), Some((y0, y1))) = (
            range(k.centre.x - r, k.centre.x + r, grid.first.x, grid.nx),
            range(k.centre.y - r, k.centre.y + r, grid.first.y, grid.ny),
        ) else {
            continue;
        };
        for iy in y0..=y1 {
            let y = grid.first.y + iy as f64 * grid.resolution;
            let row = &mut out[iy * grid.nx..(iy + 1) * grid.nx];
            for (ix, cell) in row.iter_mut().enumerate().take(x1 + 1).skip(x0) {
                let e = k.exponent(Vec2::new(grid.first.x + ix as f64 * grid.resolution, y));
                evaluations += 1;
                if e >= cutoff {
                    *cell += (scale * k.weight * e.exp()) as f32;
                }
            }
        }
    }
    evaluations
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_step_equals_the_kernel_by_hand() {
        // N_p = 1, gamma = 0.8, no growth: an obstacle at the origin moving +x at 1 m/s is
        // predicted at (0.4, 0); a point 0.3 m further along and 0.2 m to the side gets
        // 0.8 exp(-0.3^2 / (2 0.59^2) - 0.2^2 / (2 0.37^2)).
        let cfg = PredictiveCostConfig {
            steps: 1,
            growth_par: 0.0,
            growth_perp: 0.0,
            ..PredictiveCostConfig::default()
        };
        let o = [MovingObstacle {
            position: Vec2::default(),
            velocity: Vec2::new(1.0, 0.0),
        }];
        let want = 0.8 * (-0.09f64 / (2.0 * 0.59 * 0.59) - 0.04 / (2.0 * 0.37 * 0.37)).exp();
        let got = predictive_cost(Vec2::new(0.7, 0.2), &o, &cfg);
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        // The kernel turns with the motion: the same offsets, obstacle moving +y.
        let turned = [MovingObstacle {
            position: Vec2::default(),
            velocity: Vec2::new(0.0, 1.0),
        }];
        let got = predictive_cost(Vec2::new(-0.2, 0.7), &turned, &cfg);
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    }

    #[test]
    fn risk_lies_ahead_of_the_motion_and_fades_with_time() {
        let cfg = PredictiveCostConfig::default();
        let o = [MovingObstacle {
            position: Vec2::default(),
            velocity: Vec2::new(1.0, 0.0),
        }];
        let ahead = predictive_cost(Vec2::new(1.0, 0.0), &o, &cfg);
        let behind = predictive_cost(Vec2::new(-1.0, 0.0), &o, &cfg);
        let side = predictive_cost(Vec2::new(0.4, 1.0), &o, &cfg);
        assert!(ahead > 5.0 * behind, "ahead {ahead}, behind {behind}");
        assert!(ahead > side, "ahead {ahead}, side {side}");
        // At the first predicted position the field is below its peak (later steps are
        // elsewhere) and above the first step's own weight.
        let first = predictive_cost(Vec2::new(0.4, 0.0), &o, &cfg);
        assert!(first > cfg.gamma && first < cfg.peak(), "{first}");
        // A post at rest adds nothing; nor does an empty list.
        let post = [MovingObstacle {
            position: Vec2::new(1.0, 0.0),
            velocity: Vec2::new(0.01, 0.0),
        }];
        assert_eq!(predictive_cost(Vec2::new(1.0, 0.0), &post, &cfg), 0.0);
        assert_eq!(predictive_cost(Vec2::new(1.0, 0.0), &[], &cfg), 0.0);
    }

    #[test]
    fn the_grid_holds_the_field_at_its_cell_centres_up_to_the_cutoff() {
        let cfg = PredictiveCostConfig::default();
        let o = [
            MovingObstacle {
                position: Vec2::new(1.0, 0.5),
                velocity: Vec2::new(0.8, -0.6),
            },
            MovingObstacle {
                position: Vec2::new(-1.0, -1.0),
                velocity: Vec2::new(0.0, 1.2),
            },
        ];
        let grid = Grid {
            first: Vec2::new(-4.0, -5.0),
            resolution: 0.1,
            nx: 101,
            ny: 91,
        };
        let mut out = vec![0.5f32; grid.nx * grid.ny];
        let evaluations = add_to_grid(&o, &cfg, &grid, 2.0, &mut out);
        assert!(evaluations > 0 && evaluations < (2 * cfg.steps * grid.nx * grid.ny) as u64);
        // Each kernel loses at most exp(-4.5) of its weight beyond the cutoff.
        let tolerance = 2.0 * 2.0 * cfg.peak() * (-4.5f64).exp() + 1e-5;
        let mut worst = 0.0f64;
        for iy in 0..grid.ny {
            for ix in 0..grid.nx {
                let p = grid.first + Vec2::new(ix as f64, iy as f64) * grid.resolution;
                let want = 0.5 + 2.0 * predictive_cost(p, &o, &cfg);
                let got = f64::from(out[iy * grid.nx + ix]);
                assert!(got <= want + 1e-5, "({ix}, {iy}): {got} above {want}");
                worst = worst.max(want - got);
            }
        }
        assert!(worst < tolerance, "{worst}");
        // Far from every prediction the cells keep their value; an empty list adds nothing.
        assert_eq!(out[0], 0.5);
        let before = out.clone();
        assert_eq!(add_to_grid(&[], &cfg, &grid, 2.0, &mut out), 0);
        assert_eq!(out, before);
        // A kernel beyond the grid's edge visits nothing.
        let away = [MovingObstacle {
            position: Vec2::new(50.0, 0.0),
            velocity: Vec2::new(1.0, 0.0),
        }];
        assert_eq!(add_to_grid(&away, &cfg, &grid, 2.0, &mut out), 0);
    }

    #[test]
    fn bad_settings_are_named() {
        let bad = PredictiveCostConfig {
            gamma: 1.5,
            ..PredictiveCostConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().key, "gamma");
        let bad = PredictiveCostConfig {
            steps: 0,
            ..PredictiveCostConfig::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("steps"));
        PredictiveCostConfig::default().validate().unwrap();
    }
}
