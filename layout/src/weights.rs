//! The size of the policy network's flat weight vector, which the learner publishes and the
//! actors load.

/// Number of parameters of an MLP with layer sizes `dims` (input first): the sum over its
/// layers of `in * out + out` (each layer's weights, then its bias).
pub fn param_count(dims: &[usize]) -> usize {
    dims.windows(2).map(|w| w[0] * w[1] + w[1]).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_weights_and_biases_of_every_layer() {
        assert_eq!(param_count(&[3, 2]), 8);
        assert_eq!(
            param_count(&[730, 512, 512, 4]),
            730 * 512 + 512 + 512 * 512 + 512 + 512 * 4 + 4
        );
        assert_eq!(param_count(&[5]), 0);
    }
}
