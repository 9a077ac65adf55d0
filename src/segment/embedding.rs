//! An image-embedding network for the similarity step, described by a model description
//! (`model_desc`, `[output] kind = "embedding"`) or by its file name as iVS3D names them
//! (`ImageEmbedding_<NAME>_<DIM>_<W>x<H>.onnx`: one RGB W x H image, ImageNet mean and standard
//! deviation, DIM values out), run by OpenCV DNN or ONNX Runtime on the CPU. [`check`] refuses,
//! before any frame is decoded and whichever runtime is chosen, a description with a bad key, a
//! model whose declared input is not the described image or whose output does not hold DIM
//! values, naming the file (and the key). Each frame is resized to the input size (INTER_AREA)
//! and fed as the description says (`tensor::push_resized`), the same tensor for both runtimes.
//! A series is cached under [`embedder`]: a content hash of the network and its preprocessing.

use super::dnn::DnnRunner;
use super::onnx::{self, Dim};
use super::onnxrt::OrtRunner;
use super::tensor;
use crate::error::{CvContext, Error, Result};
use crate::manifest::SegRuntime;
use crate::model_desc::{is_description, Layout, ModelDesc};
use crate::steps::similarity::model_name;
use opencv::core::{Mat, CV_8UC3};
use opencv::imgproc;
use std::path::Path;

/// The description of the network at `path`: the description file itself, or the one iVS3D's
/// naming implies for an ONNX file.
pub fn describe(path: &Path) -> Result<ModelDesc> {
    if is_description(path) {
        return ModelDesc::load_embedding(path);
    }
    let name = model_name(path)?;
    Ok(ModelDesc::embedding_defaults(
        path,
        name.dim,
        name.width,
        name.height,
    ))
}

/// What says how the network is fed: `its name` or the description file.
fn sayer(desc: &ModelDesc) -> String {
    match desc.has_file() {
        true => format!("{} says", desc.path.display()),
        false => "its name says".into(),
    }
}

/// A mismatch between the model and its description: names the model, and the description
/// file and its `key` when there is one.
fn mismatch(desc: &ModelDesc, key: &str, msg: String) -> Error {
    match desc.has_file() {
        true => {
            let msg = format!("{}: {msg}", desc.model.display());
            Error::file(&desc.path, None, "model description", key, msg)
        }
        false => Error::input(&desc.model, msg),
    }
}

/// Reads the description of the network at `path` ([`describe`]) and checks it against the
/// model's declared graph without running it: the input is one 3-channel image of the
/// described size and layout (batch 1 or dynamic), the output holds `dim` values after the
/// batch; named tensors exist.
pub fn check(path: &Path) -> Result<ModelDesc> {
    let desc = describe(path)?;
    let sig = onnx::signature(&desc.model)?;
    let names = |t: &[onnx::TensorDecl]| {
        let v: Vec<&str> = t.iter().map(|d| d.name.as_str()).collect();
        v.join(", ")
    };
    let input = match &desc.input.name {
        Some(n) => sig.inputs.iter().find(|i| &i.name == n).ok_or_else(|| {
            let msg = format!("has no input named `{n}` (inputs: {})", names(&sig.inputs));
            mismatch(&desc, "input.name", msg)
        })?,
        None => &sig.inputs[0],
    };
    let output = match &desc.output.name {
        Some(n) => sig.outputs.iter().find(|o| &o.name == n).ok_or_else(|| {
            let msg = format!(
                "has no output named `{n}` (outputs: {})",
                names(&sig.outputs)
            );
            mismatch(&desc, "output.name", msg)
        })?,
        None => &sig.outputs[0],
    };
    let fixed = |d: &Dim| match d {
        Dim::Fixed(v) => Some(*v),
        Dim::Dynamic => None,
    };
    let want: Vec<i64> = (tensor::input_shape(&desc, 1).iter())
        .map(|&d| d as i64)
        .collect();
    let dims = input.shape.clone().unwrap_or_default();
    let fits = dims.len() == 4
        && dims
            .iter()
            .zip(&want)
            .all(|(d, w)| fixed(d).is_none_or(|v| v == *w));
    if !fits {
        let (w, h) = (desc.input.width, desc.input.height);
        let layout = match desc.input.layout {
            Layout::Nchw => "NCHW",
            Layout::Nhwc => "NHWC",
        };
        let msg = format!(
            "its input `{}` is {}, and {} {want:?} (one {w}x{h} image, {layout})",
            input.name,
            shape_text(&dims),
            sayer(&desc),
        );
        return Err(mismatch(&desc, "input.width", msg));
    }
    let dim = desc.output.dim.unwrap_or(0);
    let odims = output.shape.clone().unwrap_or_default();
    let values: Option<i64> = odims.iter().skip(1).map(fixed).product();
    if values.is_some_and(|v| v != dim as i64) || odims.is_empty() {
        let msg = format!(
            "its output `{}` is {}, and {} {dim} values per image",
            output.name,
            shape_text(&odims),
            sayer(&desc),
        );
        return Err(mismatch(&desc, "output.dim", msg));
    }
    Ok(desc)
}

fn shape_text(dims: &[Dim]) -> String {
    let d: Vec<String> = (dims.iter())
        .map(|d| match d {
            Dim::Fixed(v) => v.to_string(),
            Dim::Dynamic => "?".into(),
        })
        .collect();
    format!("[{}]", d.join(", "))
}

/// The name of the series the network described by `desc` computes, its cache key:
/// `onnx:<file name>:<16 hex digits>`, the digits a 64-bit FNV-1a hash (not cryptographic: it
/// tells files apart, it does not authenticate them) of the model file's bytes and of the
/// preprocessing ([`ModelDesc::preprocessing`]). A different file of the same name and size, or
/// another mean, gives another key and the embeddings are computed again.
pub fn embedder(desc: &ModelDesc) -> Result<String> {
    let h = hash_file(&desc.model)?;
    let h = crate::output::fnv1a64_update(h, desc.preprocessing().as_bytes());
    let file = desc.model.file_name().unwrap_or_default().to_string_lossy();
    Ok(format!("onnx:{file}:{h:016x}"))
}

/// [`embedder`] of the network at `path` (a description or an ONNX file); None when it cannot
/// be read (`check` says why, before this is asked).
pub fn embedder_of(path: &Path) -> Option<String> {
    embedder(&describe(path).ok()?).ok()
}

/// FNV-1a 64 of the file's bytes, read in 1 MiB pieces; remembered per (path, length, mtime)
/// within the process, so the review page's re-selections do not read a large model each time.
fn hash_file(path: &Path) -> Result<u64> {
    use std::collections::HashMap;
    use std::io::Read;
    use std::sync::Mutex;
    type Key = (std::path::PathBuf, u64, Option<std::time::SystemTime>);
    static SEEN: Mutex<Option<HashMap<Key, u64>>> = Mutex::new(None);
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    let key = (path.to_path_buf(), meta.len(), meta.modified().ok());
    if let Some(h) = (SEEN.lock().ok()).and_then(|m| m.as_ref()?.get(&key).copied()) {
        return Ok(h);
    }
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut buf = vec![0u8; 1 << 20];
    let mut h = crate::output::FNV_OFFSET;
    loop {
        let n = f.read(&mut buf).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            break;
        }
        h = crate::output::fnv1a64_update(h, &buf[..n]);
    }
    if let Ok(mut m) = SEEN.lock() {
        m.get_or_insert_with(HashMap::new).insert(key, h);
    }
    Ok(h)
}

enum Runner {
    Dnn(DnnRunner),
    Ort(OrtRunner),
}

/// A checked embedding network ready to run.
pub struct Network {
    desc: ModelDesc,
    runner: Runner,
    runtime: SegRuntime,
    input: Vec<f32>,
}

impl Network {
    /// Checks ([`check`]) and loads the network at `path` on `runtime`, then runs it once on a
    /// blank image, so a network that cannot run or gives another number of values fails here,
    /// before any frame.
    pub fn load(path: &Path, runtime: SegRuntime) -> Result<Network> {
        let desc = check(path)?;
        let runner = match runtime {
            SegRuntime::Opencv => Runner::Dnn(DnnRunner::load(&desc)?),
            // ONNX Runtime's own refusals (no library) name the step they stop.
            SegRuntime::Ort => Runner::Ort(OrtRunner::load(&desc).map_err(|e| match e {
                Error::Step { msg, .. } => Error::step(crate::steps::similarity::ID, msg),
                e => e,
            })?),
        };
        let mut net = Network {
            desc,
            runner,
            runtime,
            input: Vec::new(),
        };
        let (w, h) = net.size();
        let blank = Mat::new_rows_cols_with_default(h as i32, w as i32, CV_8UC3, 0.into())
            .cv(|| "blank image".into())?;
        net.embed(&blank)?;
        Ok(net)
    }

    /// The input size (width, height).
    pub fn size(&self) -> (u32, u32) {
        (self.desc.input.width, self.desc.input.height)
    }

    /// Values per embedding.
    pub fn dim(&self) -> usize {
        self.desc.output.dim.unwrap_or(0)
    }

    /// The runtime that runs it.
    pub fn runtime(&self) -> SegRuntime {
        self.runtime
    }

    /// The embedding of one 8-bit BGR frame.
    pub fn embed(&mut self, bgr: &Mat) -> Result<Vec<f64>> {
        self.input.clear();
        tensor::push_resized(&self.desc, bgr, imgproc::INTER_AREA, &mut self.input)?;
        let shape = tensor::input_shape(&self.desc, 1);
        let (_, values) = match &mut self.runner {
            Runner::Dnn(r) => r.run(&self.desc, &shape, &self.input)?,
            Runner::Ort(r) => r.run(&self.desc, &shape, &self.input)?,
        };
        if values.len() != self.dim() {
            let msg = format!(
                "gave {} values for an image, and {} {}",
                values.len(),
                sayer(&self.desc),
                self.dim()
            );
            return Err(mismatch(&self.desc, "output.dim", msg));
        }
        Ok(values.iter().map(|&v| f64::from(v)).collect())
    }
}
