//! The shaping terms of the reward that depend on the scan, as pure functions.
//!
//! The rest of the reward (progress, step penalty, terminal rewards) is simple arithmetic in
//! [`crate::env::AdpEnv::step`]; the parameters live in [`crate::env::EnvConfig`].

/// How many of the smallest ranges the obstacle term averages.
pub const OBSTACLE_BEAMS: usize = 10;

/// Mean of the [`OBSTACLE_BEAMS`] smallest ranges (all of them if fewer; infinity if none).
/// Allocation-free: keeps the smallest values in a fixed array.
pub fn mean_smallest_ranges(ranges: &[f64]) -> f64 {
    let mut best = [f64::INFINITY; OBSTACLE_BEAMS];
    for &r in ranges {
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
    let n = ranges.len().min(OBSTACLE_BEAMS);
    if n == 0 {
        return f64::INFINITY;
    }
    best[..n].iter().sum::<f64>() / n as f64
}

/// The obstacle penalty `scale * (1 - d / threshold)^2` when `d` (the mean of the 10 smallest
/// raw ranges) is below `threshold`, else 0. `scale` is negative for a penalty.
pub fn obstacle_penalty(ranges: &[f64], threshold: f64, scale: f64) -> f64 {
    let d = mean_smallest_ranges(ranges);
    if d < threshold {
        scale * (1.0 - d / threshold).powi(2)
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
        assert_eq!(mean_smallest_ranges(&r), 5.5);
        assert_eq!(mean_smallest_ranges(&[2.0, 4.0]), 3.0);
        assert_eq!(mean_smallest_ranges(&[]), f64::INFINITY);
        // Ties and unsorted input.
        let r = [0.3, 0.1, 0.1, 9.0, 0.2, 0.5, 0.4, 0.1, 7.0, 0.6, 0.7, 0.8, 8.0];
        let mut s = r.to_vec();
        s.sort_by(f64::total_cmp);
        let want = s[..10].iter().sum::<f64>() / 10.0;
        assert!((mean_smallest_ranges(&r) - want).abs() < 1e-15);
    }

    #[test]
    fn penalty_only_below_threshold_and_quadratic() {
        let far = vec![3.0; 720];
        assert_eq!(obstacle_penalty(&far, 0.05, -1.0), 0.0);
        let mut near = vec![3.0; 720];
        near[100..110].fill(0.025);
        assert!((obstacle_penalty(&near, 0.05, -1.0) + 0.25).abs() < 1e-12);
        near[100..110].fill(0.0);
        assert!((obstacle_penalty(&near, 0.05, -1.0) + 1.0).abs() < 1e-12);
        near[100..110].fill(0.06);
        assert_eq!(obstacle_penalty(&near, 0.05, -1.0), 0.0);
    }
}
