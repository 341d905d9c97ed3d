//! The shaping term of the reward that depends on the scan, as pure functions: the robot's
//! clearance measured from its footprint, and the obstacle penalty of that clearance.
//!
//! The rest of the reward (progress, step penalty, terminal rewards) is simple arithmetic in
//! [`crate::env::AdpEnv::step`]; the parameters live in [`crate::env::EnvConfig`].

use sim::geometry::{Footprint, Vec2};

/// How many of the smallest clearances the obstacle term averages.
pub const OBSTACLE_BEAMS: usize = 10;

/// Mean of the [`OBSTACLE_BEAMS`] smallest values (all of them if fewer; infinity if none).
/// Allocation-free: keeps the smallest values in a fixed array.
pub fn mean_smallest<I: IntoIterator<Item = f64>>(values: I) -> f64 {
    let mut best = [f64::INFINITY; OBSTACLE_BEAMS];
    let mut n = 0usize;
    for r in values {
        n += 1;
        // `best` is sorted ascending; insert r if it beats the largest kept value.
        if r < best[OBSTACLE_BEAMS - 1] {
            let mut k = OBSTACLE_BEAMS - 1;
            while k > 0 && best[k - 1] > r {
                best[k] = best[k - 1];
                k -= 1;
            }
            best[k] = r;
        }
    }
    let n = n.min(OBSTACLE_BEAMS);
    if n == 0 {
        return f64::INFINITY;
    }
    best[..n].iter().sum::<f64>() / n as f64
}

/// The robot's clearance: the mean of the [`OBSTACLE_BEAMS`] smallest distances from the
/// footprint's boundary to the lidar returns `points` (robot frame; a return inside the
/// footprint counts as 0). Infinity without returns. Allocation-free.
pub fn footprint_clearance(points: &[Vec2], footprint: &Footprint) -> f64 {
    mean_smallest(
        points
            .iter()
            .map(|&p| footprint.signed_distance_local(p).max(0.0)),
    )
}

/// The obstacle penalty `scale * (1 - d / threshold)^2` when the clearance `d` (of
/// [`footprint_clearance`]) is below `threshold`, else 0. `scale` is negative for a penalty.
pub fn obstacle_penalty(clearance: f64, threshold: f64, scale: f64) -> f64 {
    if clearance < threshold {
        scale * (1.0 - clearance / threshold).powi(2)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_of_the_ten_smallest() {
        let mut r: Vec<f64> = (0..720).map(|k| 1.0 + k as f64).collect();
        r.reverse();
        assert_eq!(mean_smallest(r.iter().copied()), 5.5);
        assert_eq!(mean_smallest([2.0, 4.0]), 3.0);
        assert_eq!(mean_smallest([]), f64::INFINITY);
        // Ties and unsorted input.
        let r = [0.3, 0.1, 0.1, 9.0, 0.2, 0.5, 0.4, 0.1, 7.0, 0.6, 0.7, 0.8, 8.0];
        let mut s = r.to_vec();
        s.sort_by(f64::total_cmp);
        let want = s[..10].iter().sum::<f64>() / 10.0;
        assert!((mean_smallest(r) - want).abs() < 1e-15);
    }

    #[test]
    fn clearance_is_measured_from_the_footprint() {
        let fp = Footprint::JACKAL; // half length 0.254, half width 0.215
                                    // Ten returns 0.1 m ahead of the front bumper, one far away: clearance 0.1 m, where
                                    // the centre-measured range would be 0.354 m.
        let mut pts = vec![Vec2::new(0.354, 0.0); 10];
        pts.push(Vec2::new(5.0, 0.0));
        assert!((footprint_clearance(&pts, &fp) - 0.1).abs() < 1e-12);
        // Beside the robot: 0.05 m off the left side; a corner point at (0.3, 0.3) is
        // hypot(0.046, 0.085) away; a point inside counts as 0.
        let side = vec![Vec2::new(0.0, 0.265); 10];
        assert!((footprint_clearance(&side, &fp) - 0.05).abs() < 1e-12);
        let corner = vec![Vec2::new(0.3, 0.3); 10];
        assert!((footprint_clearance(&corner, &fp) - 0.046f64.hypot(0.085)).abs() < 1e-12);
        assert_eq!(footprint_clearance(&[Vec2::new(0.1, 0.0); 10], &fp), 0.0);
        assert_eq!(footprint_clearance(&[], &fp), f64::INFINITY);
    }

    #[test]
    fn penalty_only_below_threshold_and_quadratic() {
        assert_eq!(obstacle_penalty(0.5, 0.2, -5.0), 0.0);
        assert!((obstacle_penalty(0.1, 0.2, -5.0) + 1.25).abs() < 1e-12);
        assert!((obstacle_penalty(0.0, 0.2, -5.0) + 5.0).abs() < 1e-12);
        assert_eq!(obstacle_penalty(0.2, 0.2, -5.0), 0.0);
        assert_eq!(obstacle_penalty(f64::INFINITY, 0.2, -5.0), 0.0);
    }
}
