//! The actor as an ONNX graph (see the [module docs](super) for its shape and names).

use prost::Message;

use policy_file::{bias_name, weight_name};
pub use policy_file::{INPUT_NAME, OPSET, OUTPUT_NAME};

use super::weights::{dense_layers, le_bytes};
use crate::nets::Actor;

/// The ONNX types generated from the official schema `proto/onnx.proto` (ONNX 1.17.0) by
/// `build.rs`. Generated code: this module uses only a few of its types, hence the allowances.
#[allow(dead_code, missing_docs, clippy::all, clippy::pedantic)]
pub(crate) mod proto {
    include!(concat!(env!("OUT_DIR"), "/onnx.rs"));
}

/// ONNX IR version of the graph: 7, the IR version that goes with opset 13 (ONNX 1.8).
pub const IR_VERSION: i64 = 7;
/// Name of the symbolic batch dimension of the ONNX input and output.
pub const BATCH_DIM: &str = "batch";

/// `float32 [batch, width]` with the symbolic batch dimension.
fn batch_value_info(name: &str, width: usize) -> proto::ValueInfoProto {
    use proto::tensor_shape_proto::{dimension::Value, Dimension};
    let dim = |value| Dimension {
        value: Some(value),
        denotation: None,
    };
    proto::ValueInfoProto {
        name: Some(name.into()),
        r#type: Some(proto::TypeProto {
            value: Some(proto::type_proto::Value::TensorType(proto::type_proto::Tensor {
                elem_type: Some(proto::tensor_proto::DataType::Float as i32),
                shape: Some(proto::TensorShapeProto {
                    dim: vec![
                        dim(Value::DimParam(BATCH_DIM.into())),
                        dim(Value::DimValue(width as i64)),
                    ],
                }),
            })),
            denotation: None,
        }),
        ..Default::default()
    }
}

fn initializer(name: String, dims: &[usize], values: &[f32]) -> proto::TensorProto {
    proto::TensorProto {
        name: Some(name),
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: Some(proto::tensor_proto::DataType::Float as i32),
        raw_data: Some(le_bytes(values)),
        ..Default::default()
    }
}

fn node(op_type: &str, name: String, input: Vec<String>, output: String) -> proto::NodeProto {
    proto::NodeProto {
        op_type: Some(op_type.into()),
        name: Some(name),
        input,
        output: vec![output],
        ..Default::default()
    }
}

/// The actor as a serialized ONNX `ModelProto` (see the module docs for the graph), with
/// `metadata` as the model's metadata properties.
pub fn actor_onnx(actor: &Actor, metadata: &[(&str, String)]) -> Vec<u8> {
    let layers = dense_layers(actor);
    let last = layers.len() - 1;
    let mut nodes = Vec::new();
    let mut initializers = Vec::new();
    let mut x = INPUT_NAME.to_string();
    for (i, layer) in layers.iter().enumerate() {
        initializers.push(initializer(
            weight_name(i),
            &[layer.fan_out, layer.fan_in],
            &layer.weight,
        ));
        initializers.push(initializer(bias_name(i), &[layer.fan_out], &layer.bias));
        let linear = format!("linear_{i}");
        let mut gemm = node(
            "Gemm",
            format!("gemm_{i}"),
            vec![x, weight_name(i), bias_name(i)],
            linear.clone(),
        );
        gemm.attribute.push(proto::AttributeProto {
            name: Some("transB".into()),
            r#type: Some(proto::attribute_proto::AttributeType::Int as i32),
            i: Some(1),
            ..Default::default()
        });
        nodes.push(gemm);
        let (op, out) = if i < last {
            ("Relu", format!("relu_{i}"))
        } else {
            ("Tanh", OUTPUT_NAME.to_string())
        };
        nodes.push(node(
            op,
            format!("{}_{i}", op.to_lowercase()),
            vec![linear],
            out.clone(),
        ));
        x = out;
    }
    let (obs_dim, act_dim) = (layers[0].fan_in, layers[last].fan_out);
    let model = proto::ModelProto {
        ir_version: Some(IR_VERSION),
        opset_import: vec![proto::OperatorSetIdProto {
            domain: Some(String::new()),
            version: Some(OPSET),
        }],
        producer_name: Some("adp".into()),
        producer_version: Some(env!("CARGO_PKG_VERSION").into()),
        doc_string: Some(
            "ADP TD3 actor: normalized observation -> action in [-1, 1]; see policy.json".into(),
        ),
        graph: Some(proto::GraphProto {
            name: Some("adp_actor".into()),
            node: nodes,
            initializer: initializers,
            input: vec![batch_value_info(INPUT_NAME, obs_dim)],
            output: vec![batch_value_info(OUTPUT_NAME, act_dim)],
            ..Default::default()
        }),
        metadata_props: metadata
            .iter()
            .map(|(key, value)| proto::StringStringEntryProto {
                key: Some((*key).into()),
                value: Some(value.clone()),
            })
            .collect(),
        ..Default::default()
    };
    model.encode_to_vec()
}
