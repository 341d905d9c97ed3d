//! Exploration noise for collecting experience: Gaussian in normalized action space.

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

/// Adds independent `N(0, sigma)` noise to every action dimension, then clamps to [-1, 1].
///
/// Seeded from a `u64`, so an actor's noise stream is reproducible. Owns its generator: one
/// per actor thread (`Send`, not shared).
#[derive(Clone, Debug)]
pub struct Exploration {
    sigma: f64,
    rng: Pcg64Mcg,
}

impl Exploration {
    /// Noise of standard deviation `sigma` (normalized action units).
    ///
    /// # Panics
    /// If `sigma` is negative or not finite.
    pub fn new(sigma: f64, seed: u64) -> Self {
        let mut e = Self {
            sigma: 0.0,
            rng: Pcg64Mcg::seed_from_u64(seed),
        };
        e.set_sigma(sigma);
        e
    }

    /// The current standard deviation.
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// Changes the standard deviation (the learner ships one with each policy version).
    ///
    /// # Panics
    /// If `sigma` is negative or not finite.
    pub fn set_sigma(&mut self, sigma: f64) {
        assert!(
            sigma.is_finite() && sigma >= 0.0,
            "exploration sigma = {sigma} must be finite and >= 0"
        );
        self.sigma = sigma;
    }

    /// Perturbs `action` in place: `a <- clamp(a + N(0, sigma), -1, 1)`. Allocation-free.
    pub fn perturb(&mut self, action: &mut [f32]) {
        for a in action {
            let z: f64 = self.rng.sample(StandardNormal);
            *a = (f64::from(*a) + self.sigma * z).clamp(-1.0, 1.0) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeded_clamped_and_of_the_right_spread() {
        let draw = |seed| {
            let mut e = Exploration::new(0.2, seed);
            let mut a = vec![0.0f32; 4000];
            e.perturb(&mut a);
            a
        };
        let a = draw(5);
        assert_eq!(a, draw(5));
        assert_ne!(a, draw(6));
        let mean = a.iter().map(|&x| f64::from(x)).sum::<f64>() / a.len() as f64;
        let sd = (a.iter().map(|&x| (f64::from(x) - mean).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
        assert!(
            mean.abs() < 0.02 && (sd - 0.2).abs() < 0.02,
            "mean {mean}, sd {sd}"
        );

        let mut e = Exploration::new(5.0, 1);
        let mut b = vec![0.9f32; 1000];
        e.perturb(&mut b);
        assert!(b.iter().all(|x| (-1.0..=1.0).contains(x)));
        assert!(
            b.contains(&1.0) && b.contains(&-1.0),
            "large noise is clamped at both ends"
        );

        let mut e = Exploration::new(0.0, 1);
        let mut c = [0.25f32, -0.5];
        e.perturb(&mut c);
        assert_eq!(c, [0.25, -0.5], "sigma 0 leaves the action alone");
        e.set_sigma(0.1);
        assert_eq!(e.sigma(), 0.1);
    }

    #[test]
    #[should_panic(expected = "must be finite and >= 0")]
    fn negative_sigma_is_refused() {
        Exploration::new(-0.1, 0);
    }
}
