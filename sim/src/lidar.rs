//! A planar lidar (Hokuyo UST-10 on the Jackal: 720 beams over 270 degrees, 0.1-30 m).

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::error::ConfigError;
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
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            beams: 720,
            fov_deg: 270.0,
            min_range: 0.1,
            max_range: 30.0,
            noise_sigma: 0.001,
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
        Ok(())
    }
}

/// A lidar with its beam directions precomputed.
#[derive(Clone, Debug)]
pub struct Lidar {
    cfg: LidarConfig,
    /// (cos, sin) of every beam angle in the robot frame.
    dirs: Vec<Vec2>,
    angles: Vec<f64>,
    noise: Option<Normal<f64>>,
}

impl Lidar {
    /// Builds the sensor. Panics only if `cfg` fails [`LidarConfig::validate`].
    pub fn new(cfg: LidarConfig) -> Self {
        cfg.validate().expect("invalid lidar config");
        let fov = cfg.fov_deg.to_radians();
        let angles: Vec<f64> = (0..cfg.beams)
            .map(|i| -fov / 2.0 + fov * i as f64 / (cfg.beams - 1) as f64)
            .collect();
        let dirs = angles.iter().map(|a| Vec2::new(a.cos(), a.sin())).collect();
        let noise = (cfg.noise_sigma > 0.0).then(|| Normal::new(0.0, cfg.noise_sigma).expect("sigma >= 0"));
        Self {
            cfg,
            dirs,
            angles,
            noise,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &LidarConfig {
        &self.cfg
    }

    /// Beam angles in the robot frame (rad), in scan order.
    pub fn angles(&self) -> &[f64] {
        &self.angles
    }

    /// Scans `scene` (a world at one moment) from `pose`, writing one range per beam into
    /// `ranges` (resized to the number of beams; no allocation once it has that size).
    pub fn scan(&self, scene: &Scene<'_>, pose: &Pose, rng: &mut impl Rng, ranges: &mut Vec<f64>) {
        ranges.resize(self.dirs.len(), 0.0);
        let o = pose.position();
        let (s, c) = pose.yaw.sin_cos();
        for (r, d) in ranges.iter_mut().zip(&self.dirs) {
            let dw = Vec2::new(c * d.x - s * d.y, s * d.x + c * d.y);
            let mut range = scene
                .raycast(o, dw, self.cfg.max_range)
                .unwrap_or(self.cfg.max_range);
            if let Some(n) = &self.noise {
                range += n.sample(rng);
            }
            *r = range.clamp(self.cfg.min_range, self.cfg.max_range);
        }
    }

    /// Every beam's end point in the robot frame: its return, or the point at max range for
    /// a beam without one (what clears free space in [`crate::costmap::Costmap::clear`]).
    pub fn ends(&self, ranges: &[f64], out: &mut Vec<Vec2>) {
        out.clear();
        out.extend(ranges.iter().zip(&self.dirs).map(|(&r, d)| *d * r));
    }

    /// Converts ranges to points in the robot frame, skipping beams at max range (no return).
    pub fn points(&self, ranges: &[f64], out: &mut Vec<Vec2>) {
        out.clear();
        for (&r, d) in ranges.iter().zip(&self.dirs) {
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
    use rand::SeedableRng;

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
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
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
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(2);
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
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
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
}
