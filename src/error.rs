//! The library's error type: every message names the file, frame index, parameter or step it is about.

use std::path::PathBuf;

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in keyframer's library code.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input (video, image folder, image) cannot be used.
    #[error("{}: {msg}", path.display())]
    Input {
        /// The input.
        path: PathBuf,
        /// What is wrong with it.
        msg: String,
    },

    /// One frame of an input could not be decoded or processed.
    #[error("{}: frame {index}: {msg}", path.display())]
    Frame {
        /// The input the frame belongs to.
        path: PathBuf,
        /// The frame's index in the input, from 0.
        index: usize,
        /// What failed.
        msg: String,
    },

    /// A file system operation failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or folder the operation was on.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: std::io::Error,
    },

    /// A command-line or workflow parameter is invalid.
    #[error("invalid value for {name}: {msg}")]
    Param {
        /// The parameter's name as the user spells it (a flag or a workflow key).
        name: String,
        /// Why the value is refused.
        msg: String,
    },

    /// A project, workflow or model file is malformed; `field` is the path of the offending key
    /// and `line` its line when known.
    #[error("{}{}: invalid {what} at `{field}`: {msg}", path.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
    File {
        /// The malformed file.
        path: PathBuf,
        /// The 1-based line of the offending key, when known.
        line: Option<usize>,
        /// What kind of file it is (project, workflow, model ...).
        what: &'static str,
        /// The dotted path of the offending key.
        field: String,
        /// What is wrong with it.
        msg: String,
    },

    /// A step (sampler, export masks) refused its input or parameters.
    #[error("plugin `{step}`: {msg}")]
    Step {
        /// The step's name.
        step: &'static str,
        /// Why it refused.
        msg: String,
    },

    /// The output location would lose existing results.
    #[error("{}: {msg}", path.display())]
    Output {
        /// The output path that is refused.
        path: PathBuf,
        /// Why.
        msg: String,
    },

    /// GPU set-up or execution failed: what failed and, where wgpu reported it, wgpu's own
    /// error (its text is part of the message too, since the binary prints one line).
    #[error("GPU: {context}{}", source.as_ref().map(|s| format!(": {s}")).unwrap_or_default())]
    Gpu {
        /// What failed and on what.
        context: String,
        /// wgpu's error, where the failure came from wgpu.
        source: Option<GpuSource>,
    },

    /// An OpenCV call failed; `context` says which one and on what. OpenCV's own texts that
    /// mean nothing to a user (size limits, allocation failures) get a sentence saying what to
    /// do, see [`explain_opencv`].
    #[cfg(feature = "opencv")]
    #[error("OpenCV {context}: {}", explain_opencv(source))]
    OpenCv {
        /// Which OpenCV call failed and on what.
        context: String,
        /// OpenCV's own error.
        #[source]
        source: opencv::Error,
    },

    /// COLMAP is missing, or one of its stages failed (the message names the stage and its log).
    #[error("{0}")]
    Colmap(String),
}

/// The wgpu errors an [`Error::Gpu`] keeps as its source. (Validation errors and device loss
/// reach keyframer through callbacks as text, since `wgpu::Error` is not `Sync`; they stay in
/// the context.)
#[derive(Debug, thiserror::Error)]
pub enum GpuSource {
    /// No device could be made on the adapter.
    #[error(transparent)]
    RequestDevice(#[from] wgpu::RequestDeviceError),
    /// Waiting for the device failed.
    #[error(transparent)]
    Poll(#[from] wgpu::PollError),
    /// Mapping a buffer for reading failed.
    #[error(transparent)]
    Map(#[from] wgpu::BufferAsyncError),
    /// A mapped buffer's range could not be read.
    #[error(transparent)]
    MapRange(#[from] wgpu::MapRangeError),
    /// An OpenCV call on the way to or from the device failed.
    #[cfg(feature = "opencv")]
    #[error(transparent)]
    OpenCv(#[from] opencv::Error),
}

impl Error {
    /// Shorthand for [`Error::Input`].
    pub fn input(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            msg: msg.into(),
        }
    }

    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    /// Shorthand for [`Error::Frame`].
    pub fn frame(path: impl Into<PathBuf>, index: usize, msg: impl Into<String>) -> Self {
        Error::Frame {
            path: path.into(),
            index,
            msg: msg.into(),
        }
    }

    /// Shorthand for [`Error::Output`].
    pub fn output(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Output {
            path: path.into(),
            msg: msg.into(),
        }
    }

    /// Shorthand for [`Error::File`].
    pub fn file(
        path: impl Into<PathBuf>,
        line: Option<usize>,
        what: &'static str,
        field: impl Into<String>,
        msg: impl Into<String>,
    ) -> Self {
        Error::File {
            path: path.into(),
            line,
            what,
            field: field.into(),
            msg: msg.into(),
        }
    }

    /// Shorthand for [`Error::Step`].
    pub fn step(step: &'static str, msg: impl Into<String>) -> Self {
        Error::Step {
            step,
            msg: msg.into(),
        }
    }

    /// An [`Error::Gpu`] with no wgpu error behind it (a check of keyframer's own).
    pub fn gpu(context: impl Into<String>) -> Self {
        Error::Gpu {
            context: context.into(),
            source: None,
        }
    }

    /// An [`Error::Gpu`] caused by wgpu's error `source`.
    pub fn gpu_from(context: impl Into<String>, source: impl Into<GpuSource>) -> Self {
        Error::Gpu {
            context: context.into(),
            source: Some(source.into()),
        }
    }

    /// Shorthand for [`Error::Param`].
    pub fn param(name: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Param {
            name: name.into(),
            msg: msg.into(),
        }
    }

    /// A parameter's or step's message without its name; any other error in full.
    pub fn into_msg(self) -> String {
        match self {
            Error::Param { msg, .. } | Error::Step { msg, .. } => msg,
            other => other.to_string(),
        }
    }
}

/// OpenCV's message for `e`, preceded by what it means and what to do when it is one of the
/// texts a user cannot act on: the image size limits of imgcodecs (CV_IO_MAX_IMAGE_PIXELS,
/// _WIDTH, _HEIGHT) and failed allocations. The raw text follows in brackets.
#[cfg(feature = "opencv")]
pub fn explain_opencv(e: &opencv::Error) -> String {
    let raw = e.message.trim();
    let hint = if raw.contains("CV_IO_MAX_IMAGE_PIXELS")
        || raw.contains("CV_IO_MAX_IMAGE_WIDTH")
        || raw.contains("CV_IO_MAX_IMAGE_HEIGHT")
        || raw.contains("validateInputImageSize")
    {
        Some(
            "the image is larger than OpenCV reads (at most 2^30 pixels and 2^20 pixels a side, \
             from the size in its header): use a smaller image, or raise the limit with the \
             environment variable OPENCV_IO_MAX_IMAGE_PIXELS"
                .to_string(),
        )
    } else if let Some(bytes) = failed_allocation(raw) {
        Some(format!(
            "out of memory: OpenCV could not allocate {} for this: use a smaller input or output \
             size (export --resize / --scale / --crop, --analysis-width)",
            human_bytes(bytes)
        ))
    } else if raw.contains("Insufficient memory") || raw.contains("out of memory") {
        Some(
            "out of memory: use a smaller input or output size (export --resize / --scale / \
             --crop, --analysis-width)"
                .to_string(),
        )
    } else {
        None
    };
    match hint {
        Some(h) => format!("{h} [OpenCV: {raw}]"),
        None => raw.to_string(),
    }
}

/// N of OpenCV's "Failed to allocate N bytes".
#[cfg(feature = "opencv")]
fn failed_allocation(raw: &str) -> Option<u64> {
    let rest = &raw[raw.find("Failed to allocate ")? + "Failed to allocate ".len()..];
    rest.split_whitespace().next()?.parse().ok()
}

#[cfg(feature = "opencv")]
fn human_bytes(b: u64) -> String {
    const GIB: f64 = (1u64 << 30) as f64;
    if b as f64 >= GIB {
        format!("{:.1} GiB ({b} bytes)", b as f64 / GIB)
    } else {
        format!("{b} bytes")
    }
}

/// Attaches a description of the failed OpenCV call to an `opencv::Result`.
#[cfg(feature = "opencv")]
pub trait CvContext<T> {
    /// Converts the OpenCV error into [`Error::OpenCv`] with `context`.
    fn cv(self, context: impl FnOnce() -> String) -> Result<T>;
}

#[cfg(feature = "opencv")]
impl<T> CvContext<T> for opencv::Result<T> {
    fn cv(self, context: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|source| Error::OpenCv {
            context: context(),
            source,
        })
    }
}

#[cfg(all(test, feature = "opencv"))]
mod tests {
    use super::*;

    fn cv_err(msg: &str) -> Error {
        Error::OpenCv {
            context: "imread big.png".into(),
            source: opencv::Error::new(opencv::core::StsAssert, msg),
        }
    }

    #[test]
    fn opencv_size_and_memory_errors_say_what_to_do() {
        let e = cv_err("OpenCV(4.6.0) ./modules/imgcodecs/src/loadsave.cpp:77: error: (-215:Assertion failed) pixels <= CV_IO_MAX_IMAGE_PIXELS in function 'validateInputImageSize'").to_string();
        assert!(
            e.starts_with("OpenCV imread big.png: the image is larger than OpenCV reads"),
            "{e}"
        );
        assert!(e.contains("OPENCV_IO_MAX_IMAGE_PIXELS"), "{e}");
        let e = cv_err("OpenCV(4.6.0) ./modules/core/src/alloc.cpp:73: error: (-4:Insufficient memory) Failed to allocate 30000000000 bytes in function 'OutOfMemoryError'").to_string();
        assert!(
            e.contains("could not allocate 27.9 GiB (30000000000 bytes)"),
            "{e}"
        );
        assert!(e.contains("--resize"), "{e}");
        // Other messages pass through unchanged.
        assert_eq!(cv_err("odd").to_string(), "OpenCV imread big.png: odd");
    }
}
