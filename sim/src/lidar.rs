//! A planar lidar (Hokuyo UST-10 on the Jackal: 720 beams over 270 degrees, 0.1-30 m), with
//! the sensing conditions of robustness studies: fewer beams, range noise absolute or relative
//! to the scan, and beam dropout.

use rand::{Rng, SeedableRng};
use rand_distr::{Bernoulli, Distribution, Normal, StandardNormal};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use crate::error::ConfigError;
use crate::fan::Fan;
use crate::geometry::{Pose, Vec2};
use crate::world::Scene;

/// Lidar parameters. Defaults are the UST-10 of the BARN Jackal.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LidarConfig {
    /// Number of beams, spread evenly from -fov/2 to +fov/2 inclusive.
    pub beams: usize,
    /// Field of view (degrees), centred on the robot's heading.
    pub fov_deg: f64,
    /// Smallest reported range (m); closer returns are reported as this value.
    pub min_range: f64,
    /// Largest range (m); a beam that hits nothing reports this value.
    pub max_range: f64,
    /// Standard deviation of the Gaussian range noise (m); 0 disables noise.
    pub noise_sigma: f64,
    /// Gaussian range noise relative to the scene: the standard deviation of every beam's noise
    /// is this fraction of the scan's mean range over the beams with a return (computed per
    /// scan, before noise; a scan without a return gets none). 0 (the default) disables it;
    /// at most 1. Exclusive with `noise_sigma`: one of the two must be 0.
    pub noise_fraction: f64,
    /// Probability that a beam returns no reading, drawn per beam and scan: a dropped beam
    /// reads `max_range`, exactly as a beam that hits nothing (no point, nothing marked in the
    /// map). In [0, 1); 0 (the default) drops nothing.
    pub dropout: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            beams: 720,
            fov_deg: 270.0,
            min_range: 0.1,
            max_range: 30.0,
            noise_sigma: 0.001,
            noise_fraction: 0.0,
            dropout: 0.0,
        }
    }
}

impl LidarConfig {
    /// Checks that the values make a usable sensor.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.beams < 2 {
            return Err(ConfigError::value(
                "lidar.beams",
                self.beams as f64,
                "must be at least 2",
            ));
        }
        if !(self.fov_deg > 0.0 && self.fov_deg <= 360.0) {
            return Err(ConfigError::value(
                "lidar.fov_deg",
                self.fov_deg,
                "must be in (0, 360]",
            ));
        }
        if !(self.min_range >= 0.0 && self.max_range > self.min_range) {
            return Err(ConfigError::LidarRanges {
                min: self.min_range,
                max: self.max_range,
            });
        }
        if !(self.noise_sigma >= 0.0 && self.noise_sigma.is_finite()) {
            return Err(ConfigError::value(
                "lidar.noise_sigma",
                self.noise_sigma,
                "must be >= 0",
            ));
        }
        if !(0.0..=1.0).contains(&self.noise_fraction) {
            return Err(ConfigError::value(
                "lidar.noise_fraction",
                self.noise_fraction,
                "must be in [0, 1] (a fraction of the scan's mean range)",
            ));
        }
        if self.noise_fraction > 0.0 && self.noise_sigma > 0.0 {
            return Err(ConfigError::value(
                "lidar.noise_fraction",
                self.noise_fraction,
                format!(
                    "is exclusive with lidar.noise_sigma = {}: set noise_sigma = 0 to give the \
                     noise as a fraction of the scan's mean range",
                    self.noise_sigma
                ),
            ));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return Err(ConfigError::value(
                "lidar.dropout",
                self.dropout,
                "must be in [0, 1) (the probability that a beam returns nothing)",
            ));
        }
        Ok(())
    }
}

/// Seed offset of the dropout stream, apart from the noise stream so that turning dropout on
/// leaves every beam's noise draw as it was.
const DROPOUT_STREAM: u64 = 0x5eed_d209_7000_0004;

/// The lidar's random streams, both seeded from one run seed: range noise (the seed's own
/// stream, what the sensor always drew from) and beam dropout (a stream apart).
#[derive(Clone, Debug)]
pub struct LidarRng {
    noise: Pcg64Mcg,
    dropout: Pcg64Mcg,
}

impl LidarRng {
    /// The streams of run seed `seed`.
    pub fn new(seed: u64) -> Self {
        Self {
            noise: Pcg64Mcg::seed_from_u64(seed),
            dropout: Pcg64Mcg::seed_from_u64(seed ^ DROPOUT_STREAM),
        }
    }
}

/// A lidar with its beam directions precomputed.
#[derive(Clone, Debug)]
pub struct Lidar {
    cfg: LidarConfig,
    /// The beams, evenly over the field of view (robot frame).
    fan: Fan,
    noise: Option<Normal<f64>>,
    dropout: Option<Bernoulli>,
}

impl Lidar {
    /// Builds the sensor. Panics only if `cfg` fails [`LidarConfig::validate`].
    pub fn new(cfg: LidarConfig) -> Self {
        cfg.validate().expect("invalid lidar config");
        let fov = cfg.fov_deg.to_radians();
        let fan = Fan::new(cfg.beams, -fov / 2.0, fov / 2.0);
        let noise = (cfg.noise_sigma > 0.0).then(|| Normal::new(0.0, cfg.noise_sigma).expect("sigma >= 0"));
        let dropout = (cfg.dropout > 0.0).then(|| Bernoulli::new(cfg.dropout).expect("dropout in [0, 1)"));
        Self {
            cfg,
            fan,
            noise,
            dropout,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &LidarConfig {
        &self.cfg
    }

    /// Beam angles in the robot frame (rad), in scan order.
    pub fn angles(&self) -> &[f64] {
        self.fan.angles()
    }

    /// Scans `scene` (a world at one moment) from `pose`, writing one range per beam into
    /// `ranges` (resized to the number of beams; no allocation once it has that size).
    ///
    /// Every beam draws its noise from `rng`'s noise stream in beam order (absolute noise, then
    /// the relative noise of `noise_fraction`, each only when enabled), then its dropout from
    /// the dropout stream (only when enabled); the range is clamped to `[min_range,
    /// max_range]` last. With the defaults a beam draws one absolute noise value and nothing
    /// else.
    pub fn scan(&self, scene: &Scene<'_>, pose: &Pose, rng: &mut LidarRng, ranges: &mut Vec<f64>) {
        self.fan.cast(scene, pose, self.cfg.max_range, ranges);
        let (mut returned, mut returns) = (0.0, 0usize);
        for r in ranges.iter_mut() {
            if r.is_finite() {
                returned += *r;
                returns += 1;
            } else {
                *r = self.cfg.max_range;
            }
        }
        let relative_sigma = if returns > 0 {
            self.cfg.noise_fraction * returned / returns as f64
        } else {
            0.0
        };
        for r in ranges.iter_mut() {
            let mut range = *r;
            if let Some(n) = &self.noise {
                range += n.sample(&mut rng.noise);
            }
            if relative_sigma > 0.0 {
                let z: f64 = rng.noise.sample(StandardNormal);
                range += relative_sigma * z;
            }
            if self.dropout.is_some_and(|d| d.sample(&mut rng.dropout)) {
                range = self.cfg.max_range;
            }
            *r = range.clamp(self.cfg.min_range, self.cfg.max_range);
        }
    }

    /// Every beam's end point in the robot frame: its return, or the point at max range for
    /// a beam without one (what clears free space in [`crate::costmap::Costmap::clear`]).
    pub fn ends(&self, ranges: &[f64], out: &mut Vec<Vec2>) {
        out.clear();
        out.extend(ranges.iter().zip(self.fan.dirs()).map(|(&r, d)| *d * r));
    }

    /// Converts ranges to points in the robot frame, skipping beams at max range (no return).
    pub fn points(&self, ranges: &[f64], out: &mut Vec<Vec2>) {
        out.clear();
        for (&r, d) in ranges.iter().zip(self.fan.dirs()) {
            if r < self.cfg.max_range {
                out.push(*d * r);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Circle;
    use crate::motion::{MovingCylinder, Trajectory};
    use crate::world::World;

    fn one_cylinder(x: f64, y: f64, r: f64) -> World {
        World::new(
            0,
            vec![Circle {
                c: Vec2::new(x, y),
                r,
            }],
            Pose::default(),
            Vec2::new(9.0, 0.0),
            9.0,
            vec![],
        )
    }

    #[test]
    fn ranges_match_hand_geometry() {
        let cfg = LidarConfig {
            noise_sigma: 0.0,
            ..Default::default()
        };
        let lidar = Lidar::new(cfg);
        let mut rng = LidarRng::new(1);
        let mut ranges = Vec::new();
        // Cylinder of radius 0.5 at (3, 0); robot at the origin facing +x.
        let w = one_cylinder(3.0, 0.0, 0.5);
        lidar.scan(&w.at(0.0), &Pose::new(0.0, 0.0, 0.0), &mut rng, &mut ranges);
        assert_eq!(ranges.len(), 720);
        // 720 beams over 270 deg inclusive: beam k is at -135 + k * 270/719 deg; the beams at
        // +-0.1878 deg bracket the heading.
        let mid = 359;
        let a = lidar.angles()[mid];
        // Ray y = tan(a) x hits the circle (x-3)^2 + y^2 = 0.25 at the smaller root.
        let (ca, sa) = (a.cos(), a.sin());
        let b = -3.0 * ca;
        let expect = -b - (b * b - (9.0 - 0.25)).sqrt();
        assert!((ranges[mid] - expect).abs() < 1e-9, "{} vs {expect}", ranges[mid]);
        assert!((expect - 2.5).abs() < 1e-3);
        let _ = sa;
        // Beams pointing away see nothing: max range.
        assert_eq!(ranges[0], 30.0);
        assert_eq!(ranges[719], 30.0);
        // The same cylinder seen from a robot facing +y is on its right (negative angles).
        lidar.scan(
            &w.at(0.0),
            &Pose::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            &mut rng,
            &mut ranges,
        );
        let k = lidar
            .angles()
            .iter()
            .position(|&a| a >= -std::f64::consts::FRAC_PI_2)
            .unwrap();
        assert!((ranges[k] - 2.5).abs() < 2e-3, "{}", ranges[k]);
        // Points are robot-frame positions of the returns.
        let mut pts = Vec::new();
        lidar.points(&ranges, &mut pts);
        assert!(pts
            .iter()
            .all(|p| (p.dist(Vec2::new(0.0, -3.0)) - 0.5).abs() < 1e-6));
    }

    #[test]
    fn min_range_and_noise() {
        let w = one_cylinder(0.12, 0.0, 0.1);
        let lidar = Lidar::new(LidarConfig {
            noise_sigma: 0.0,
            ..Default::default()
        });
        let mut rng = LidarRng::new(2);
        let mut ranges = Vec::new();
        lidar.scan(&w.at(0.0), &Pose::default(), &mut rng, &mut ranges);
        assert_eq!(ranges[359], 0.1, "returns closer than min_range are clamped");

        let far = one_cylinder(5.0, 0.0, 1.0);
        let noisy = Lidar::new(LidarConfig {
            noise_sigma: 0.01,
            ..Default::default()
        });
        let mut errs = Vec::new();
        for _ in 0..200 {
            noisy.scan(&far.at(0.0), &Pose::default(), &mut rng, &mut ranges);
            errs.push(ranges[359] - 4.0);
        }
        let mean = errs.iter().sum::<f64>() / errs.len() as f64;
        let sd = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errs.len() as f64).sqrt();
        assert!(
            mean.abs() < 0.003 && (sd - 0.01).abs() < 0.003,
            "mean {mean} sd {sd}"
        );
    }

    #[test]
    fn a_moving_cylinder_is_seen_where_it_is_at_the_scan_time() {
        // A cylinder of radius 0.5 crossing the robot's heading along x = 4: keyframes
        // (0 s: (4, -3)), (2 s: (4, 0)), (4 s: (4, 3)). Catmull-Rom tangents (per segment):
        // m0 = (p1 - p0) / 2 = (0, 1.5), m1 = (p2 - p0) / 2 = (0, 3).
        let tr = Trajectory::new(&[[0.0, 4.0, -3.0], [2.0, 4.0, 0.0], [4.0, 4.0, 3.0]], 4.0).unwrap();
        let w = World::new(0, vec![], Pose::default(), Vec2::new(9.0, 0.0), 9.0, vec![]).with_moving(vec![
            MovingCylinder {
                radius: 0.5,
                trajectory: tr,
            },
        ]);
        let lidar = Lidar::new(LidarConfig {
            noise_sigma: 0.0,
            ..Default::default()
        });
        let mut rng = LidarRng::new(3);
        let mut ranges = Vec::new();
        // Beam 359, 0.1878 deg right of the heading.
        let mid = 359;
        let a = lidar.angles()[mid];
        let d = Vec2::new(a.cos(), a.sin());
        // The near root of |t d - c|^2 = r^2 for a centre c.
        let hit = |c: Vec2| {
            let b = d.dot(c);
            b - (b * b - c.dot(c) + 0.25).sqrt()
        };
        // t = 1 s (s = 0.5 in segment 0; h00 = h01 = 0.5, h10 = 0.125, h11 = -0.125):
        // y = 0.5 (-3) + 0.125 (1.5) - 0.125 (3) = -1.6875, 1.19 m off the beam: no return.
        assert!(w.at(1.0).moving()[0].c.dist(Vec2::new(4.0, -1.6875)) < 1e-12);
        lidar.scan(&w.at(1.0), &Pose::default(), &mut rng, &mut ranges);
        assert_eq!(ranges[mid], 30.0);
        // t = 1.75 s (s = 0.875: h00 = 0.04296875, h10 = 0.013671875, h11 = -0.095703125):
        // y = -3 (0.04296875) + 1.5 (0.013671875) + 3 (-0.095703125) = -0.3955078125; the beam
        // cuts the cylinder off-centre.
        let c = Vec2::new(4.0, -0.3955078125);
        assert!(w.at(1.75).moving()[0].c.dist(c) < 1e-12);
        lidar.scan(&w.at(1.75), &Pose::default(), &mut rng, &mut ranges);
        assert!((ranges[mid] - hit(c)).abs() < 1e-9, "{}", ranges[mid]);
        assert!((ranges[mid] - 3.68).abs() < 0.01, "{}", ranges[mid]);
        // t = 2 s: the keyframe (4, 0), nearly face on: 3.5 m.
        lidar.scan(&w.at(2.0), &Pose::default(), &mut rng, &mut ranges);
        assert!(
            (ranges[mid] - hit(Vec2::new(4.0, 0.0))).abs() < 1e-9,
            "{}",
            ranges[mid]
        );
        assert!((ranges[mid] - 3.5).abs() < 1e-3);
    }

    /// Two cylinders at 1.5 m (right) and 3 m (left) of a 3-beam lidar over 180 degrees,
    /// whose middle beam sees nothing: the scan's mean range over its returns is 2.25 m.
    fn two_returns() -> (World, LidarConfig) {
        let w = World::new(
            0,
            vec![
                Circle {
                    c: Vec2::new(0.0, -2.0),
                    r: 0.5,
                },
                Circle {
                    c: Vec2::new(0.0, 4.0),
                    r: 1.0,
                },
            ],
            Pose::default(),
            Vec2::new(9.0, 0.0),
            9.0,
            vec![],
        );
        let cfg = LidarConfig {
            beams: 3,
            fov_deg: 180.0,
            noise_sigma: 0.0,
            ..Default::default()
        };
        (w, cfg)
    }

    #[test]
    fn the_default_noise_is_one_gaussian_draw_per_beam_from_the_seed() {
        // What the sensor drew before sensing conditions existed: N(0, 0.001) per beam in beam
        // order from the run seed's own stream, and nothing else.
        let w = one_cylinder(3.0, 0.0, 0.5);
        let clean = Lidar::new(LidarConfig {
            noise_sigma: 0.0,
            ..Default::default()
        });
        let mut truth = Vec::new();
        clean.scan(&w.at(0.0), &Pose::default(), &mut LidarRng::new(5), &mut truth);
        let mut ranges = Vec::new();
        Lidar::new(LidarConfig::default()).scan(
            &w.at(0.0),
            &Pose::default(),
            &mut LidarRng::new(5),
            &mut ranges,
        );
        let normal = Normal::new(0.0, 0.001).unwrap();
        let mut stream = Pcg64Mcg::seed_from_u64(5);
        for (k, (&r, &t)) in ranges.iter().zip(&truth).enumerate() {
            let want = (t + normal.sample(&mut stream)).clamp(0.1, 30.0);
            assert_eq!(r.to_bits(), want.to_bits(), "beam {k}");
        }
    }

    #[test]
    fn noise_fraction_scales_with_the_scans_mean_return() {
        let (w, cfg) = two_returns();
        let mut truth = Vec::new();
        Lidar::new(cfg).scan(&w.at(0.0), &Pose::default(), &mut LidarRng::new(1), &mut truth);
        assert!((truth[0] - 1.5).abs() < 1e-12 && truth[1] == 30.0 && (truth[2] - 3.0).abs() < 1e-12);
        // sigma = 0.1 x (1.5 + 3) / 2 = 0.225 m; every beam draws z ~ N(0, 1) from the noise
        // stream in beam order (the one without a return too: 30 + noise, clamped).
        let noisy = Lidar::new(LidarConfig {
            noise_fraction: 0.1,
            ..cfg
        });
        let mut rng = LidarRng::new(7);
        let mut stream = Pcg64Mcg::seed_from_u64(7);
        let mut ranges = Vec::new();
        let mut errs = Vec::new();
        for _ in 0..2000 {
            noisy.scan(&w.at(0.0), &Pose::default(), &mut rng, &mut ranges);
            for (k, (&r, &t)) in ranges.iter().zip(&truth).enumerate() {
                let z: f64 = stream.sample(StandardNormal);
                let want = (t + 0.225 * z).clamp(0.1, 30.0);
                assert!((r - want).abs() < 1e-12, "beam {k}: {r} vs {want}");
            }
            errs.push(ranges[0] - truth[0]);
        }
        let n = errs.len() as f64;
        let mean = errs.iter().sum::<f64>() / n;
        let sd = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!(
            (sd - 0.225).abs() < 0.015 && mean.abs() < 0.02,
            "mean {mean} sd {sd}"
        );
        // Without a return there is nothing to scale: no noise at all.
        let empty = World::new(0, vec![], Pose::default(), Vec2::new(9.0, 0.0), 9.0, vec![]);
        noisy.scan(&empty.at(0.0), &Pose::default(), &mut rng, &mut ranges);
        assert_eq!(ranges, vec![30.0; 3]);
    }

    #[test]
    fn dropout_empties_beams_at_its_rate_and_leaves_the_rest_as_they_were() {
        // 1000 beams over 10 degrees all hit a cylinder of radius 2 at 5 m (it spans +-23.6
        // degrees); 100 scans: 100,000 beams. Dropped beams read max range. With p = 0.1 the
        // count is Binomial(100000, 0.1): mean 10,000, sd 94.9; the seed is fixed, the bound is
        // 5 sd.
        let w = one_cylinder(5.0, 0.0, 2.0);
        let base = LidarConfig {
            beams: 1000,
            fov_deg: 10.0,
            noise_sigma: 0.01,
            ..Default::default()
        };
        let (plain, dropping) = (Lidar::new(base), Lidar::new(LidarConfig { dropout: 0.1, ..base }));
        let (mut a, mut b) = (LidarRng::new(11), LidarRng::new(11));
        let (mut ra, mut rb) = (Vec::new(), Vec::new());
        let mut dropped = 0usize;
        for _ in 0..100 {
            plain.scan(&w.at(0.0), &Pose::default(), &mut a, &mut ra);
            dropping.scan(&w.at(0.0), &Pose::default(), &mut b, &mut rb);
            assert!(ra.iter().all(|&r| r < 3.1), "every beam returns");
            for (&x, &y) in ra.iter().zip(&rb) {
                if y == 30.0 {
                    dropped += 1;
                } else {
                    assert_eq!(x.to_bits(), y.to_bits(), "a kept beam keeps its noise draw");
                }
            }
        }
        assert!(
            (dropped as f64 - 10_000.0).abs() < 475.0,
            "{dropped} of 100000 dropped"
        );
    }

    #[test]
    fn invalid_conditions_name_the_field_and_value() {
        let err = |cfg: LidarConfig| cfg.validate().unwrap_err().to_string();
        let both = err(LidarConfig {
            noise_fraction: 0.1,
            ..Default::default()
        });
        assert!(
            both.starts_with("lidar.noise_fraction = 0.1 is exclusive with lidar.noise_sigma = 0.001"),
            "{both}"
        );
        let e = err(LidarConfig {
            noise_sigma: 0.0,
            noise_fraction: 1.5,
            ..Default::default()
        });
        assert!(
            e.starts_with("lidar.noise_fraction = 1.5 must be in [0, 1]"),
            "{e}"
        );
        let e = err(LidarConfig {
            dropout: 1.0,
            ..Default::default()
        });
        assert!(e.starts_with("lidar.dropout = 1 must be in [0, 1)"), "{e}");
        let e = err(LidarConfig {
            dropout: f64::NAN,
            ..Default::default()
        });
        assert!(e.starts_with("lidar.dropout = NaN"), "{e}");
        assert!(LidarConfig {
            noise_sigma: 0.0,
            noise_fraction: 0.2,
            dropout: 0.5,
            ..Default::default()
        }
        .validate()
        .is_ok());
    }
}
