//! The actor's weights as safetensors: the writer ([`actor_safetensors`]); the reader and the
//! tensor names ([`weight_name`], [`bias_name`]) are the `policy-file` crate's.

use std::collections::HashMap;

use burn::tensor::Tensor;
use policy_file::weights::{bias_name, weight_name};
use safetensors::tensor::{Dtype, TensorView};

use crate::nets::Actor;

/// One dense layer of the actor in PyTorch's layout.
pub(super) struct Dense {
    /// `[fan_out, fan_in]`, row-major.
    pub(super) weight: Vec<f32>,
    /// `[fan_out]`.
    pub(super) bias: Vec<f32>,
    pub(super) fan_in: usize,
    pub(super) fan_out: usize,
}

/// The actor's layers, input side first, with weights transposed from burn's `[in, out]`.
pub(super) fn dense_layers(actor: &Actor) -> Vec<Dense> {
    actor
        .layers()
        .iter()
        .map(|layer| {
            let [fan_in, fan_out] = layer.weight.dims();
            let w = to_vec(layer.weight.val());
            let mut weight = vec![0.0; fan_in * fan_out];
            for i in 0..fan_in {
                for o in 0..fan_out {
                    weight[o * fan_in + i] = w[i * fan_out + o];
                }
            }
            let bias = layer
                .bias
                .as_ref()
                .map_or_else(|| vec![0.0; fan_out], |b| to_vec(b.val()));
            Dense {
                weight,
                bias,
                fan_in,
                fan_out,
            }
        })
        .collect()
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .try_to_vec::<f32>()
        .expect("actor parameters are f32")
}

pub(super) fn le_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// The actor's weights as a safetensors file (names and layout in the module docs), with
/// `metadata` in the header's `__metadata__`.
pub fn actor_safetensors(
    actor: &Actor,
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>, safetensors::SafeTensorError> {
    let layers = dense_layers(actor);
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (i, layer) in layers.iter().enumerate() {
        tensors.push((
            weight_name(i),
            vec![layer.fan_out, layer.fan_in],
            le_bytes(&layer.weight),
        ));
        tensors.push((bias_name(i), vec![layer.fan_out], le_bytes(&layer.bias)));
    }
    let views = tensors
        .iter()
        .map(|(name, shape, bytes)| Ok((name.as_str(), TensorView::new(Dtype::F32, shape.clone(), bytes)?)))
        .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()?;
    safetensors::serialize(views, Some(metadata))
}
