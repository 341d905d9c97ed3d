//! CPU inference of the actor MLP from the flat weights the learner publishes.
//!
//! Flat layout, for each linear layer `l` in order (`in = dims[l]`, `out = dims[l + 1]`): the
//! weight matrix `[in][out]` row-major (`w[i * out + o]`, burn's `Linear` layout, `y = x W + b`),
//! then the bias `[out]`. Hidden layers use ReLU, the output layer tanh, so actions are in
//! [-1, 1]. The default actor is `[730, 512, 512, 4]`.

/// A policy network that cannot be built from the given sizes and weights.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PolicyError {
    /// Fewer than two layer sizes, or a zero size.
    #[error("layer sizes {dims:?}: need at least an input and an output size, all > 0")]
    Dims {
        /// The sizes given.
        dims: Vec<usize>,
    },
    /// The flat vector does not have the length the sizes imply.
    #[error("layer sizes {dims:?} need {expected} parameters, got {got}")]
    Length {
        /// The sizes given.
        dims: Vec<usize>,
        /// `param_count(dims)`.
        expected: usize,
        /// The flat vector's length.
        got: usize,
    },
    /// A NaN or infinite parameter.
    #[error("parameter {index} is {value}: weights must be finite")]
    NotFinite {
        /// Position in the flat vector.
        index: usize,
        /// The value.
        value: f32,
    },
}

/// Number of parameters of an MLP with layer sizes `dims` (defined with the observation layout
/// in the `layout` crate, which the learner reads too).
pub use layout::param_count;

/// The actor MLP with its weights in the flat layout of the module docs. Immutable and
/// `Sync`: one instance may serve many threads, each with its own [`Scratch`].
#[derive(Clone, Debug, PartialEq)]
pub struct MlpPolicy {
    dims: Vec<usize>,
    weights: Vec<f32>,
}

/// Reusable activation buffers for [`MlpPolicy::act`]; one per thread. They grow to the
/// widest hidden layer on first use and are not reallocated afterwards.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    a: Vec<f32>,
    b: Vec<f32>,
}

impl MlpPolicy {
    /// Builds the policy from layer sizes and flat weights; refuses sizes that make no
    /// network, a vector of the wrong length and non-finite values.
    pub fn from_flat(dims: &[usize], flat: Vec<f32>) -> Result<Self, PolicyError> {
        if dims.len() < 2 || dims.contains(&0) {
            return Err(PolicyError::Dims { dims: dims.to_vec() });
        }
        let expected = param_count(dims);
        if flat.len() != expected {
            return Err(PolicyError::Length {
                dims: dims.to_vec(),
                expected,
                got: flat.len(),
            });
        }
        if let Some((index, &value)) = flat.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(PolicyError::NotFinite { index, value });
        }
        Ok(Self {
            dims: dims.to_vec(),
            weights: flat,
        })
    }

    /// Layer sizes, input first.
    pub fn dims(&self) -> &[usize] {
        &self.dims
    }

    /// Observation length.
    pub fn obs_dim(&self) -> usize {
        self.dims[0]
    }

    /// Action length.
    pub fn act_dim(&self) -> usize {
        self.dims[self.dims.len() - 1]
    }

    /// The deterministic action of `obs`, written to `out` (in [-1, 1]). Allocation-free once
    /// `scratch` is warm.
    ///
    /// # Panics
    /// If `obs.len() != self.obs_dim()` or `out.len() != self.act_dim()`.
    pub fn act(&self, obs: &[f32], out: &mut [f32], scratch: &mut Scratch) {
        assert_eq!(obs.len(), self.obs_dim(), "observation length");
        assert_eq!(out.len(), self.act_dim(), "action length");
        let widest = self.dims[1..self.dims.len() - 1]
            .iter()
            .copied()
            .max()
            .unwrap_or(0);
        scratch.a.resize(widest, 0.0);
        scratch.b.resize(widest, 0.0);
        let last = self.dims.len() - 2;
        let mut offset = 0;
        for l in 0..=last {
            let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
            let (w, rest) = self.weights[offset..].split_at(n_in * n_out);
            let bias = &rest[..n_out];
            offset += n_in * n_out + n_out;
            // Input: the observation for the first layer, else the previous layer's output,
            // which always ends up in `scratch.a`.
            let x = if l == 0 { obs } else { &scratch.a[..n_in] };
            if l == last {
                linear(x, w, bias, out);
                out.iter_mut().for_each(|v| *v = v.tanh());
            } else {
                let y = &mut scratch.b[..n_out];
                linear(x, w, bias, y);
                y.iter_mut().for_each(|v| *v = v.max(0.0));
                std::mem::swap(&mut scratch.a, &mut scratch.b);
            }
        }
    }
}

/// Outputs per block of [`linear`]: 32 `f32` accumulators stay in registers (eight SSE or
/// four AVX registers) while every input row adds to them, so the outputs are neither loaded
/// nor stored once per input.
const BLOCK: usize = 32;

/// `y = x W + b` with `W` row-major `[x.len()][y.len()]`: each output starts at its bias and
/// adds `x[i] * W[i][o]` for `i` in ascending order, one multiply and one add each (never
/// fused); rows with `x[i] == 0` are skipped (with finite weights they add exactly zero). On a
/// CPU with AVX2 (detected at run time) the same code runs compiled for 256-bit lanes: every
/// output sees the same operations in the same order, so the values are the same bit for bit.
fn linear(x: &[f32], w: &[f32], bias: &[f32], y: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        unsafe { linear_avx2(x, w, bias, y) };
        return;
    }
    linear_blocks(x, w, bias, y);
}

/// [`linear_blocks`] compiled with AVX2 enabled.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn linear_avx2(x: &[f32], w: &[f32], bias: &[f32], y: &mut [f32]) {
    linear_blocks(x, w, bias, y);
}

/// The portable body of [`linear`]: outputs in blocks of [`BLOCK`] (the last one shorter),
/// each block's accumulators held across all input rows.
#[inline(always)]
fn linear_blocks(x: &[f32], w: &[f32], bias: &[f32], y: &mut [f32]) {
    let n_out = y.len();
    let full = n_out - n_out % BLOCK;
    for start in (0..full).step_by(BLOCK) {
        let mut acc = [0.0f32; BLOCK];
        acc.copy_from_slice(&bias[start..start + BLOCK]);
        for (&xi, row) in x.iter().zip(w.chunks_exact(n_out)) {
            if xi == 0.0 {
                continue;
            }
            let row: &[f32; BLOCK] = row[start..start + BLOCK].try_into().expect("block");
            for (a, &wij) in acc.iter_mut().zip(row) {
                *a += xi * wij;
            }
        }
        y[start..start + BLOCK].copy_from_slice(&acc);
    }
    if full < n_out {
        let tail = &mut y[full..];
        tail.copy_from_slice(&bias[full..]);
        for (&xi, row) in x.iter().zip(w.chunks_exact(n_out)) {
            if xi == 0.0 {
                continue;
            }
            for (a, &wij) in tail.iter_mut().zip(&row[full..]) {
                *a += xi * wij;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    fn random_flat(dims: &[usize], seed: u64) -> Vec<f32> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut flat = Vec::new();
        for w in dims.windows(2) {
            let bound = (1.0 / w[0] as f32).sqrt() * 2.0;
            flat.extend((0..w[0] * w[1] + w[1]).map(|_| rng.random_range(-bound..bound)));
        }
        flat
    }

    /// Straightforward f64 forward pass: out-major loops, no buffer reuse.
    fn naive(dims: &[usize], flat: &[f32], obs: &[f32]) -> Vec<f64> {
        let mut x: Vec<f64> = obs.iter().map(|&v| f64::from(v)).collect();
        let mut off = 0;
        for l in 0..dims.len() - 1 {
            let (n, m) = (dims[l], dims[l + 1]);
            let y: Vec<f64> = (0..m)
                .map(|o| {
                    let s: f64 = (0..n).map(|i| x[i] * f64::from(flat[off + i * m + o])).sum();
                    let z = s + f64::from(flat[off + n * m + o]);
                    if l == dims.len() - 2 {
                        z.tanh()
                    } else {
                        z.max(0.0)
                    }
                })
                .collect();
            off += n * m + m;
            x = y;
        }
        x
    }

    #[test]
    fn matches_a_naive_forward_pass() {
        let mut rng = Pcg64Mcg::seed_from_u64(99);
        for (k, dims) in [
            vec![730, 512, 512, 4],
            vec![5, 3],
            vec![7, 9, 2],
            vec![6, 4, 8, 5, 3],
        ]
        .into_iter()
        .enumerate()
        {
            let flat = random_flat(&dims, k as u64);
            let p = MlpPolicy::from_flat(&dims, flat.clone()).unwrap();
            assert_eq!((p.obs_dim(), p.act_dim()), (dims[0], dims[dims.len() - 1]));
            let mut scratch = Scratch::default();
            let mut out = vec![0.0; p.act_dim()];
            for _ in 0..5 {
                let mut obs: Vec<f32> = (0..dims[0]).map(|_| rng.random_range(-1.0..1.0)).collect();
                obs[0] = 0.0; // exercises the zero-input skip
                p.act(&obs, &mut out, &mut scratch);
                let want = naive(&dims, &flat, &obs);
                for (a, b) in out.iter().zip(&want) {
                    assert!((f64::from(*a) - b).abs() < 1e-5, "{dims:?}: {a} vs {b}");
                    assert!(a.abs() <= 1.0);
                }
            }
        }
    }

    /// The per-row axpy `linear` replaced: the same operations per output in the same order.
    fn linear_rows(x: &[f32], w: &[f32], bias: &[f32], y: &mut [f32]) {
        y.copy_from_slice(bias);
        for (&xi, row) in x.iter().zip(w.chunks_exact(y.len())) {
            if xi == 0.0 {
                continue;
            }
            for (acc, &wij) in y.iter_mut().zip(row) {
                *acc += xi * wij;
            }
        }
    }

    #[test]
    fn blocked_layers_equal_the_row_by_row_sum_bit_for_bit() {
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        // Widths below, at and across the block size, and the default actor's.
        for (n_in, n_out) in [(730, 512), (3, 1), (5, 31), (9, 32), (17, 33), (40, 100)] {
            let w: Vec<f32> = (0..n_in * n_out).map(|_| rng.random_range(-1.0..1.0)).collect();
            let b: Vec<f32> = (0..n_out).map(|_| rng.random_range(-1.0..1.0)).collect();
            let x: Vec<f32> = (0..n_in)
                .map(|i| {
                    if i % 7 == 3 {
                        0.0
                    } else {
                        rng.random_range(-2.0..2.0)
                    }
                })
                .collect();
            let mut want = vec![0.0; n_out];
            linear_rows(&x, &w, &b, &mut want);
            let mut got = vec![f32::NAN; n_out];
            linear_blocks(&x, &w, &b, &mut got);
            let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "portable {n_in}x{n_out}");
            let mut got = vec![f32::NAN; n_out];
            linear(&x, &w, &b, &mut got);
            assert_eq!(bits(&got), bits(&want), "dispatched {n_in}x{n_out}");
        }
    }

    #[test]
    fn scratch_reuse_across_networks_is_harmless() {
        let big = MlpPolicy::from_flat(&[4, 16, 4], random_flat(&[4, 16, 4], 1)).unwrap();
        let small = MlpPolicy::from_flat(&[4, 3, 2], random_flat(&[4, 3, 2], 2)).unwrap();
        let obs = [0.5, -0.25, 0.125, 1.0];
        let (mut fresh, mut shared) = (Scratch::default(), Scratch::default());
        let (mut a, mut b) = ([0.0; 4], [0.0; 2]);
        big.act(&obs, &mut a, &mut shared);
        small.act(&obs, &mut b, &mut shared);
        let mut c = [0.0; 2];
        small.act(&obs, &mut c, &mut fresh);
        assert_eq!(b, c);
    }

    #[test]
    fn param_count_and_refusals() {
        assert_eq!(
            param_count(&[730, 512, 512, 4]),
            730 * 512 + 512 + 512 * 512 + 512 + 512 * 4 + 4
        );
        assert_eq!(param_count(&[3, 2]), 8);
        let err = MlpPolicy::from_flat(&[3, 2], vec![0.0; 7]).unwrap_err();
        assert_eq!(
            err,
            PolicyError::Length {
                dims: vec![3, 2],
                expected: 8,
                got: 7
            }
        );
        assert!(err.to_string().contains("need 8 parameters, got 7"), "{err}");
        assert!(MlpPolicy::from_flat(&[3, 2], vec![0.0; 9]).is_err());
        let mut flat = vec![0.0; 8];
        flat[5] = f32::INFINITY;
        assert_eq!(
            MlpPolicy::from_flat(&[3, 2], flat).unwrap_err(),
            PolicyError::NotFinite {
                index: 5,
                value: f32::INFINITY
            }
        );
        assert!(matches!(
            MlpPolicy::from_flat(&[3], vec![]),
            Err(PolicyError::Dims { .. })
        ));
        assert!(matches!(
            MlpPolicy::from_flat(&[3, 0, 2], vec![2.0]),
            Err(PolicyError::Dims { .. })
        ));
    }
}
