//! The BARN score of one run.

/// BARN score: `success * OT / clip(AT, 2 OT, 8 OT)`, where OT is the optimal time and AT the
/// actual traversal time. At most 0.5 (a run at least twice as slow as optimal scores
/// `OT / AT`; faster runs are clipped to 0.5), 0 for a failed run.
pub fn barn_score(success: bool, optimal_time: f64, actual_time: f64) -> f64 {
    if !success {
        return 0.0;
    }
    optimal_time / actual_time.clamp(2.0 * optimal_time, 8.0 * optimal_time)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values_and_clip_bounds() {
        // World 0: OT = 6.796149 s.
        let ot = 6.796149;
        assert_eq!(
            barn_score(true, ot, 10.0),
            0.5,
            "faster than 2 OT is clipped to 0.5"
        );
        assert!((barn_score(true, ot, 20.0) - ot / 20.0).abs() < 1e-15);
        assert!((barn_score(true, ot, 27.184596) - 0.25).abs() < 1e-12);
        assert_eq!(
            barn_score(true, ot, 1000.0),
            0.125,
            "slower than 8 OT is clipped to 1/8"
        );
        assert_eq!(barn_score(false, ot, 10.0), 0.0);
    }
}
