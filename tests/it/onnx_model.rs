//! Writes tiny ONNX models for the tests (a hand-rolled protobuf encoder, a few hundred bytes per
//! model): a 1x1 convolution with chosen weights, optionally followed by a sigmoid, and their
//! model descriptions.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

fn varint(out: &mut Vec<u8>, mut v: u64) {
    loop {
        let b = (v & 0x7f) as u8;
        v >>= 7;
        if v == 0 {
            out.push(b);
            return;
        }
        out.push(b | 0x80);
    }
}

fn key(out: &mut Vec<u8>, field: u64, wire: u64) {
    varint(out, field << 3 | wire);
}

fn int(out: &mut Vec<u8>, field: u64, v: i64) {
    key(out, field, 0);
    varint(out, v as u64);
}

fn bytes(out: &mut Vec<u8>, field: u64, b: &[u8]) {
    key(out, field, 2);
    varint(out, b.len() as u64);
    out.extend_from_slice(b);
}

fn string(out: &mut Vec<u8>, field: u64, s: &str) {
    bytes(out, field, s.as_bytes());
}

/// TensorProto with float data.
fn tensor(name: &str, dims: &[i64], values: &[f32]) -> Vec<u8> {
    let mut t = Vec::new();
    for &d in dims {
        int(&mut t, 1, d);
    }
    int(&mut t, 2, 1); // FLOAT
    string(&mut t, 8, name);
    let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    bytes(&mut t, 9, &raw);
    t
}

/// ValueInfoProto of a float tensor; `None` dims are dynamic.
fn value_info(name: &str, dims: &[Option<i64>]) -> Vec<u8> {
    let mut shape = Vec::new();
    for d in dims {
        let mut dim = Vec::new();
        match d {
            Some(v) => int(&mut dim, 1, *v),
            None => string(&mut dim, 2, "N"),
        }
        bytes(&mut shape, 1, &dim);
    }
    let mut tensor_type = Vec::new();
    int(&mut tensor_type, 1, 1);
    bytes(&mut tensor_type, 2, &shape);
    let mut type_proto = Vec::new();
    bytes(&mut type_proto, 1, &tensor_type);
    let mut vi = Vec::new();
    string(&mut vi, 1, name);
    bytes(&mut vi, 2, &type_proto);
    vi
}

/// AttributeProto of type INTS.
fn ints_attribute(name: &str, values: &[i64]) -> Vec<u8> {
    let mut a = Vec::new();
    string(&mut a, 1, name);
    for &v in values {
        int(&mut a, 8, v);
    }
    int(&mut a, 20, 7); // INTS
    a
}

fn node(op: &str, inputs: &[&str], outputs: &[&str], name: &str) -> Vec<u8> {
    let mut n = Vec::new();
    for i in inputs {
        string(&mut n, 1, i);
    }
    for o in outputs {
        string(&mut n, 2, o);
    }
    string(&mut n, 3, name);
    string(&mut n, 4, op);
    if op == "Conv" {
        // OpenCV 4.6 does not infer the kernel shape from the weights.
        bytes(&mut n, 5, &ints_attribute("kernel_shape", &[1, 1]));
    }
    n
}

/// A model `input` [batch,3,h,w] (NCHW) -> Conv 1x1 with `weights` [k][3] and `bias` [k] ->
/// (`sigmoid`: Sigmoid) -> `scores` [batch,k,h,w]. `batch` None makes the batch dynamic.
pub fn conv1x1(
    h: i64,
    w: i64,
    batch: Option<i64>,
    weights: &[[f32; 3]],
    bias: &[f32],
    sigmoid: bool,
) -> Vec<u8> {
    let k = weights.len() as i64;
    let flat: Vec<f32> = weights.iter().flatten().copied().collect();
    let mut graph = Vec::new();
    let conv_out = if sigmoid { "logits" } else { "scores" };
    bytes(
        &mut graph,
        1,
        &node("Conv", &["input", "W", "B"], &[conv_out], "conv"),
    );
    if sigmoid {
        bytes(
            &mut graph,
            1,
            &node("Sigmoid", &["logits"], &["scores"], "sigmoid"),
        );
    }
    string(&mut graph, 2, "tiny");
    bytes(&mut graph, 5, &tensor("W", &[k, 3, 1, 1], &flat));
    bytes(&mut graph, 5, &tensor("B", &[k], bias));
    bytes(
        &mut graph,
        11,
        &value_info("input", &[batch, Some(3), Some(h), Some(w)]),
    );
    bytes(
        &mut graph,
        12,
        &value_info("scores", &[batch, Some(k), Some(h), Some(w)]),
    );
    let mut model = Vec::new();
    int(&mut model, 1, 8); // ir_version
    string(&mut model, 2, "keyframer-tests");
    bytes(&mut model, 7, &graph);
    let mut opset = Vec::new();
    string(&mut opset, 1, "");
    int(&mut opset, 2, 13);
    bytes(&mut model, 8, &opset);
    model
}

/// Weights (rows: classes; columns: R, G, B) and biases of the tiny 3-class model.
pub const W3: [[f32; 3]; 3] = [[1.0, -0.5, 0.0], [0.0, 1.0, -0.5], [-0.5, 0.0, 1.0]];
pub const B3: [f32; 3] = [0.0, 0.05, -0.05];
/// Weights of the tiny probability model (one logit).
pub const W1: [[f32; 3]; 1] = [[2.0, -1.0, -1.5]];
pub const B1: [f32; 1] = [0.1];

/// Writes the tiny model and its description into `dir`; returns the description's path.
pub fn tiny_model(
    dir: &Path,
    name: &str,
    probability: bool,
    batch: Option<i64>,
    extra: &str,
) -> PathBuf {
    let (w, h) = (12, 8);
    let model = if probability {
        conv1x1(h, w, batch, &W1, &B1, true)
    } else {
        conv1x1(h, w, batch, &W3, &B3, false)
    };
    std::fs::write(dir.join(format!("{name}.onnx")), model).unwrap();
    let (classes, kind) = if probability {
        (r#"["keep", "hide"]"#, "probability")
    } else {
        (r#"["red", "green", "blue"]"#, "scores")
    };
    let desc = dir.join(format!("{name}.toml"));
    let batch_line = if batch.is_none() { "batch = 3\n" } else { "" };
    std::fs::write(
        &desc,
        format!(
            "model = \"{name}.onnx\"\nframework = \"onnx\"\nclasses = {classes}\n{extra}\n\
             [input]\nwidth = {w}\nheight = {h}\nlayout = \"nchw\"\nchannels = \"rgb\"\n\
             scale = 0.00392156862745098\n{batch_line}\n[output]\nkind = \"{kind}\"\n"
        ),
    )
    .unwrap();
    desc
}

/// An image-embedding model: `input` [1,3,h,w] -> Conv 1x1 with `weights` [k][3] (no bias) ->
/// GlobalAveragePool -> Flatten -> `embedding` [1,k] (each value a weighted mean of the
/// normalised R, G, B over the image).
pub fn embedding_net(h: i64, w: i64, weights: &[[f32; 3]]) -> Vec<u8> {
    let k = weights.len() as i64;
    let flat: Vec<f32> = weights.iter().flatten().copied().collect();
    let mut graph = Vec::new();
    bytes(
        &mut graph,
        1,
        &node("Conv", &["input", "W", "B"], &["maps"], "conv"),
    );
    bytes(
        &mut graph,
        1,
        &node("GlobalAveragePool", &["maps"], &["pooled"], "pool"),
    );
    bytes(
        &mut graph,
        1,
        &node("Flatten", &["pooled"], &["embedding"], "flatten"),
    );
    string(&mut graph, 2, "tiny-embedding");
    bytes(&mut graph, 5, &tensor("W", &[k, 3, 1, 1], &flat));
    bytes(&mut graph, 5, &tensor("B", &[k], &vec![0.0; k as usize]));
    bytes(
        &mut graph,
        11,
        &value_info("input", &[Some(1), Some(3), Some(h), Some(w)]),
    );
    bytes(
        &mut graph,
        12,
        &value_info("embedding", &[Some(1), Some(k)]),
    );
    let mut model = Vec::new();
    int(&mut model, 1, 8); // ir_version
    string(&mut model, 2, "keyframer-tests");
    bytes(&mut model, 7, &graph);
    let mut opset = Vec::new();
    string(&mut opset, 1, "");
    int(&mut opset, 2, 13);
    bytes(&mut model, 8, &opset);
    model
}
