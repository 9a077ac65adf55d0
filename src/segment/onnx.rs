//! Reads the declared graph inputs and outputs of an ONNX file (names and shapes) with a minimal
//! protobuf walker, so a description that does not fit the model is refused before any frame,
//! whichever runtime is used.

use crate::error::{Error, Result};
use std::path::Path;

/// One dimension of a declared tensor shape.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Dim {
    /// A fixed size.
    Fixed(i64),
    /// A named or unknown (dynamic) size.
    Dynamic,
}

/// A declared graph input or output.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TensorDecl {
    /// Tensor name.
    pub name: String,
    /// Shape, when declared.
    pub shape: Option<Vec<Dim>>,
}

/// Graph inputs (initializers excluded) and outputs of an ONNX model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Signature {
    /// Real inputs, in order.
    pub inputs: Vec<TensorDecl>,
    /// Outputs, in order.
    pub outputs: Vec<TensorDecl>,
}

/// Reads the signature of the ONNX model at `path`.
pub fn signature(path: &Path) -> Result<Signature> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&bytes).map_err(|msg| Error::input(path, format!("not a readable ONNX model: {msg}")))
}

fn parse(bytes: &[u8]) -> std::result::Result<Signature, String> {
    let graph = messages(bytes, 7)?.pop().ok_or("no graph")?;
    let mut inputs = Vec::new();
    let mut outputs = Vec::new();
    let mut initializers = Vec::new();
    for f in fields(graph)? {
        match f {
            (11, Value::Bytes(b)) => inputs.push(value_info(b)?),
            (12, Value::Bytes(b)) => outputs.push(value_info(b)?),
            (5, Value::Bytes(b)) => initializers
                .extend((messages(b, 8)?.iter()).map(|n| String::from_utf8_lossy(n).into_owned())),
            _ => {}
        }
    }
    inputs.retain(|i| !initializers.contains(&i.name));
    if inputs.is_empty() || outputs.is_empty() {
        return Err("the graph declares no inputs or no outputs".into());
    }
    Ok(Signature { inputs, outputs })
}

fn value_info(b: &[u8]) -> std::result::Result<TensorDecl, String> {
    let mut name = String::new();
    let mut shape = None;
    for f in fields(b)? {
        match f {
            (1, Value::Bytes(n)) => name = String::from_utf8_lossy(n).into_owned(),
            (2, Value::Bytes(t)) => {
                // TypeProto.tensor_type (1) -> Tensor.shape (2) -> dim (1)
                for tensor in messages(t, 1)? {
                    for sh in messages(tensor, 2)? {
                        let mut dims = Vec::new();
                        for dim in messages(sh, 1)? {
                            let mut v = Dim::Dynamic;
                            for x in fields(dim)? {
                                if let (1, Value::Varint(n)) = x {
                                    v = Dim::Fixed(n as i64);
                                }
                            }
                            dims.push(v);
                        }
                        shape = Some(dims);
                    }
                }
            }
            _ => {}
        }
    }
    Ok(TensorDecl { name, shape })
}

/// The length-delimited values of field `n` of message `b`, in order.
fn messages(b: &[u8], n: u64) -> std::result::Result<Vec<&[u8]>, String> {
    let bytes = fields(b)?.into_iter().filter_map(|f| match f {
        (k, Value::Bytes(v)) if k == n => Some(v),
        _ => None,
    });
    Ok(bytes.collect())
}

enum Value<'a> {
    Varint(u64),
    Bytes(&'a [u8]),
    Fixed,
}

fn fields(mut b: &[u8]) -> std::result::Result<Vec<(u64, Value<'_>)>, String> {
    let mut out = Vec::new();
    while !b.is_empty() {
        let key = varint(&mut b)?;
        let (field, wire) = (key >> 3, key & 7);
        let v = match wire {
            0 => Value::Varint(varint(&mut b)?),
            1 | 5 => {
                let n = if wire == 1 { 8 } else { 4 };
                if b.len() < n {
                    return Err("truncated".into());
                }
                b = &b[n..];
                Value::Fixed
            }
            2 => {
                let n = usize::try_from(varint(&mut b)?).map_err(|_| "length overflow")?;
                if b.len() < n {
                    return Err("truncated".into());
                }
                let (head, tail) = b.split_at(n);
                b = tail;
                Value::Bytes(head)
            }
            w => return Err(format!("unsupported wire type {w}")),
        };
        out.push((field, v));
    }
    Ok(out)
}

fn varint(b: &mut &[u8]) -> std::result::Result<u64, String> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let (&byte, rest) = b.split_first().ok_or("truncated varint")?;
        *b = rest;
        v |= u64::from(byte & 0x7f) << shift;
        if byte & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err("varint too long".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_selfie_models_signature() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("target/models/selfie/selfie_segmentation.onnx");
        if !p.exists() {
            eprintln!("SKIPPED: {} not present: run scripts/setup.sh", p.display());
            return;
        }
        let s = signature(&p).map_err(|e| e.to_string()).unwrap();
        assert_eq!(s.inputs.len(), 1);
        assert_eq!(
            s.inputs[0].shape,
            Some(vec![
                Dim::Fixed(1),
                Dim::Fixed(256),
                Dim::Fixed(256),
                Dim::Fixed(3)
            ])
        );
        assert_eq!(s.outputs.len(), 1);
    }

    #[test]
    fn rejects_garbage() {
        assert!(parse(b"\xff\xff\xff").is_err());
        assert!(parse(b"").is_err());
    }
}
