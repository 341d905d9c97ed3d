//! A laser mounted off the base origin: [`Reprojection`] turns its scan into the scan a
//! laser of the same geometry at the base origin, facing the heading, would take, so the
//! costmap, the planners and the policy see the scan as they saw it in training (a laser at
//! the base origin). Each return is moved into the base frame and kept in the base-centred
//! beam nearest its bearing, the nearest return winning, as robot stacks turn a point cloud
//! into a scan (ROS's `pointcloud_to_laserscan`). A base-centred beam that gets no return
//! reads as none (the max range); returns outside the field of view or past the max range
//! from the base origin are dropped, and one nearer than the min range reads as the min
//! range.

use sim::geometry::{Pose, Vec2};
use sim::lidar::Lidar;

/// The re-projection of one mounted laser's scans (see the module docs). Built once per
/// navigator; allocation-free once its output has the beam count.
#[derive(Clone, Debug)]
pub(crate) struct Reprojection {
    /// The laser's pose in the base frame.
    mount: Pose,
    /// Each beam's unit direction in the laser's frame.
    dirs: Vec<Vec2>,
    /// The first beam's angle (rad) and the step between beams.
    first: f64,
    step: f64,
    min_range: f64,
    max_range: f64,
}

impl Reprojection {
    /// The re-projection of the scans of `lidar` (its beams in its own frame) mounted at
    /// `mount` (x, y in m and yaw in rad in the base frame) into a laser of the same
    /// geometry at the base origin.
    pub(crate) fn new(lidar: &Lidar, mount: Pose) -> Self {
        let angles = lidar.angles();
        let cfg = lidar.config();
        Self {
            mount,
            dirs: angles.iter().map(|a| Vec2::new(a.cos(), a.sin())).collect(),
            first: angles[0],
            step: (angles[angles.len() - 1] - angles[0]) / (angles.len() - 1) as f64,
            min_range: cfg.min_range,
            max_range: cfg.max_range,
        }
    }

    /// Writes into `out` (resized to the beam count) the base-centred scan of the mounted
    /// laser's `ranges` (checked: every value in `[min_range, max_range]`, the max range
    /// meaning no return).
    pub(crate) fn apply(&self, ranges: &[f64], out: &mut Vec<f64>) {
        let beams = self.dirs.len();
        out.clear();
        out.resize(beams, self.max_range);
        let (s, c) = self.mount.yaw.sin_cos();
        for (&r, d) in ranges.iter().zip(&self.dirs) {
            if r >= self.max_range {
                continue;
            }
            let (lx, ly) = (d.x * r, d.y * r);
            let p = Vec2::new(self.mount.x + c * lx - s * ly, self.mount.y + s * lx + c * ly);
            let range = p.norm();
            if range >= self.max_range {
                continue;
            }
            let k = ((p.y.atan2(p.x) - self.first) / self.step).round();
            if !(0.0..=(beams - 1) as f64).contains(&k) {
                continue;
            }
            let slot = &mut out[k as usize];
            *slot = slot.min(range.max(self.min_range));
        }
    }
}

#[cfg(test)]
mod tests {
    use sim::lidar::LidarConfig;

    use super::*;

    fn lidar(beams: usize, fov_deg: f64) -> Lidar {
        Lidar::new(LidarConfig {
            beams,
            fov_deg,
            ..LidarConfig::default()
        })
    }

    /// The ranges a laser at `mount` (base frame) measures to the wall x = `wall` (base
    /// frame), max range where its beam does not meet it.
    fn wall_scan(lidar: &Lidar, mount: Pose, wall: f64) -> Vec<f64> {
        let max = lidar.config().max_range;
        lidar
            .angles()
            .iter()
            .map(|a| {
                let dir = (mount.yaw + a).cos();
                let t = (wall - mount.x) / dir;
                if dir > 0.0 && t < max {
                    t
                } else {
                    max
                }
            })
            .collect()
    }

    #[test]
    fn a_laser_forward_of_the_base_sees_the_wall_at_the_base_range() {
        let lidar = lidar(720, 270.0);
        let mount = Pose::new(0.5, 0.1, 0.0);
        let scan = wall_scan(&lidar, mount, 3.0);
        // The laser sees the wall 2.5 m ahead; from the base origin it is 3 m ahead.
        assert!((scan[lidar.angles().len() / 2] - 2.5).abs() < 0.01);
        let mut base = Vec::new();
        Reprojection::new(&lidar, mount).apply(&scan, &mut base);
        assert_eq!(base.len(), 720);
        let angles = lidar.angles();
        let mut filled = 0;
        for (k, &r) in base.iter().enumerate() {
            if r < 30.0 {
                // Every return lies on the wall as seen from the base, within the bearing
                // quantum of one beam.
                let x = r * angles[k].cos();
                assert!(
                    (x - 3.0).abs() < 0.05 * r.max(1.0),
                    "beam {k}: {r} m gives x = {x}"
                );
                filled += 1;
            }
        }
        // The wall spans (-90, 90) degrees as the base sees it, up to where it passes 30 m:
        // most of the 480 beams there see it.
        assert!(filled > 400, "{filled} beams see the wall");
        // Straight ahead: 3 m, not the laser's 2.5 m.
        assert!((base[angles.len() / 2] - 3.0).abs() < 0.01, "{}", base[360]);
    }

    #[test]
    fn a_laser_facing_backwards_puts_its_returns_behind_and_the_front_is_free() {
        let lidar = lidar(1081, 270.0);
        // Mounted at the back, facing backwards: the wall x = -2 is in front of it.
        let mount = Pose::new(-0.3, 0.0, std::f64::consts::PI);
        let scan = wall_scan(&lidar, mount, -2.0);
        let mut base = Vec::new();
        Reprojection::new(&lidar, mount).apply(&scan, &mut base);
        let angles = lidar.angles();
        for (k, &r) in base.iter().enumerate() {
            if r < 30.0 {
                assert!(angles[k].cos() < 0.0, "a return ahead at beam {k}");
                assert!((r * angles[k].cos() + 2.0).abs() < 0.05 * r.max(1.0));
            }
        }
        // Straight ahead sees nothing.
        assert_eq!(base[540], 30.0);
        assert!(base.iter().any(|&r| r < 30.0));
    }

    #[test]
    fn near_and_absent_returns_are_kept_in_range() {
        let lidar = lidar(90, 360.0);
        let mut base = Vec::new();
        // A return 0.05 m from the base (inside the min range) and no returns elsewhere.
        let mut scan = vec![30.0; 90];
        // Beam 0 points backwards from the laser at (0.2, 0): 0.05 m behind the base origin.
        scan[0] = 0.25;
        Reprojection::new(&lidar, Pose::new(0.2, 0.0, 0.0)).apply(&scan, &mut base);
        assert_eq!(base.iter().filter(|&&r| r < 30.0).count(), 1);
        assert_eq!(base.iter().copied().fold(f64::INFINITY, f64::min), 0.1);
    }
}
