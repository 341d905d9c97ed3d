//! The actor's weights as safetensors: the reader ([`read_actor_safetensors`]) and the tensor
//! names, defined once ([`weight_name`], [`bias_name`]) for the learner's writer and this
//! reader.

use safetensors::tensor::{Dtype, SafeTensors};
use thiserror::Error;

/// The safetensors (and ONNX initializer) name of layer `i`'s weight.
pub fn weight_name(i: usize) -> String {
    format!("layers.{i}.weight")
}

/// The safetensors (and ONNX initializer) name of layer `i`'s bias.
pub fn bias_name(i: usize) -> String {
    format!("layers.{i}.bias")
}

/// Why [`read_actor_safetensors`] refused a file; the messages name the tensor (and element).
#[derive(Debug, Error)]
pub enum WeightsError {
    /// Not a safetensors file, or a damaged one.
    #[error("not a readable safetensors file: {0}")]
    Unreadable(String),
    /// A tensor the layer sizes need is missing.
    #[error("no tensor {name} (policy.json's layer_sizes {dims:?} need {layers} layers)")]
    Missing {
        /// The tensor.
        name: String,
        /// The layer sizes.
        dims: Vec<usize>,
        /// Their number of layers.
        layers: usize,
    },
    /// A tensor is not float32.
    #[error("tensor {name} is {dtype}, expected F32")]
    Dtype {
        /// The tensor.
        name: String,
        /// Its dtype.
        dtype: String,
    },
    /// A tensor's shape does not fit the layer sizes.
    #[error("tensor {name} has shape {shape:?}, policy.json's layer_sizes {dims:?} need {want:?}")]
    Shape {
        /// The tensor.
        name: String,
        /// Its shape.
        shape: Vec<usize>,
        /// The layer sizes.
        dims: Vec<usize>,
        /// The shape they need.
        want: Vec<usize>,
    },
    /// A value is NaN or infinite.
    #[error("{name}{index} is {value}: weights must be finite")]
    NonFinite {
        /// The tensor.
        name: String,
        /// The element, e.g. `[3, 7]`.
        index: String,
        /// The value.
        value: f32,
    },
    /// The file holds a tensor the layer sizes do not have.
    #[error("tensor {name} is not part of policy.json's layer_sizes {dims:?}")]
    Extra {
        /// The tensor.
        name: String,
        /// The layer sizes.
        dims: Vec<usize>,
    },
}

/// Reads the float32 tensors `weight_name` (`[out, in]`) and `bias_name` (`[out]`) of the
/// safetensors file `bytes` (as the learner's `export::actor_safetensors` writes them) for the
/// layer sizes `dims` and returns them in the flat layout of the `adp-policy` crate's
/// `MlpPolicy` (the learner's `Actor::flat_weights`): per layer the weight `[in][out]` row-major, then the bias. Refuses
/// a damaged file, other dtypes, shapes or extra tensors, and non-finite values.
pub fn read_actor_safetensors(bytes: &[u8], dims: &[usize]) -> Result<Vec<f32>, WeightsError> {
    let file = SafeTensors::deserialize(bytes).map_err(|e| WeightsError::Unreadable(e.to_string()))?;
    let layers = dims.len() - 1;
    let mut flat = Vec::with_capacity(layout::param_count(dims));
    let mut used = 0;
    for l in 0..layers {
        let (n_in, n_out) = (dims[l], dims[l + 1]);
        let tensor = |name: String, shape: &[usize]| -> Result<Vec<f32>, WeightsError> {
            let view = file.tensor(&name).map_err(|_| WeightsError::Missing {
                name: name.clone(),
                dims: dims.to_vec(),
                layers,
            })?;
            if view.dtype() != Dtype::F32 {
                return Err(WeightsError::Dtype {
                    name,
                    dtype: view.dtype().to_string(),
                });
            }
            if view.shape() != shape {
                return Err(WeightsError::Shape {
                    name,
                    shape: view.shape().to_vec(),
                    dims: dims.to_vec(),
                    want: shape.to_vec(),
                });
            }
            let values: Vec<f32> = view
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect();
            if let Some(k) = values.iter().position(|v| !v.is_finite()) {
                let index = if shape.len() == 2 {
                    format!("[{}, {}]", k / shape[1], k % shape[1])
                } else {
                    format!("[{k}]")
                };
                return Err(WeightsError::NonFinite {
                    name,
                    index,
                    value: values[k],
                });
            }
            Ok(values)
        };
        let weight = tensor(weight_name(l), &[n_out, n_in])?;
        let bias = tensor(bias_name(l), &[n_out])?;
        used += 2;
        // [out, in] (PyTorch) -> [in][out] (burn, MlpPolicy).
        for i in 0..n_in {
            flat.extend((0..n_out).map(|o| weight[o * n_in + i]));
        }
        flat.extend(bias);
    }
    if file.len() != used {
        let mut names = file.names();
        names.sort_unstable();
        let extra = names
            .into_iter()
            .find(|n| !(0..layers).any(|l| *n == weight_name(l) || *n == bias_name(l)))
            .unwrap_or_default();
        return Err(WeightsError::Extra {
            name: extra.to_string(),
            dims: dims.to_vec(),
        });
    }
    Ok(flat)
}
