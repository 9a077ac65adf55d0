//! The library's error type: every message names the file, frame index, parameter or plugin it is about.

use std::path::PathBuf;

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in keyframer's library code.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input (video, image folder, image) cannot be used.
    #[error("{}: {msg}", path.display())]
    Input { path: PathBuf, msg: String },

    /// One frame of an input could not be decoded or processed.
    #[error("{}: frame {index}: {msg}", path.display())]
    Frame {
        path: PathBuf,
        index: usize,
        msg: String,
    },

    /// A file system operation failed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// A command-line or workflow parameter is invalid.
    #[error("invalid value for {name}: {msg}")]
    Param { name: String, msg: String },

    /// A project, workflow or model file is malformed; `field` is the path of the offending key
    /// and `line` its line when known.
    #[error("{}{}: invalid {what} at `{field}`: {msg}", path.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
    File {
        path: PathBuf,
        line: Option<usize>,
        what: &'static str,
        field: String,
        msg: String,
    },

    /// A sampler or transform refused its input or parameters.
    #[error("plugin `{plugin}`: {msg}")]
    Plugin { plugin: &'static str, msg: String },

    /// The output location would lose existing results.
    #[error("{}: {msg}", path.display())]
    Output { path: PathBuf, msg: String },

    /// GPU set-up or execution failed.
    #[error("GPU: {0}")]
    Gpu(String),

    /// An OpenCV call failed; `context` says which one and on what.
    #[error("OpenCV {context}: {source}")]
    OpenCv {
        context: String,
        #[source]
        source: opencv::Error,
    },

    /// COLMAP is missing, or one of its stages failed (the message names the stage and its log).
    #[error("{0}")]
    Colmap(String),
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

    /// Shorthand for [`Error::Param`].
    pub fn param(name: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Param {
            name: name.into(),
            msg: msg.into(),
        }
    }
}

/// Attaches a description of the failed OpenCV call to an `opencv::Result`.
pub trait CvContext<T> {
    /// Converts the OpenCV error into [`Error::OpenCv`] with `context`.
    fn cv(self, context: impl FnOnce() -> String) -> Result<T>;
}

impl<T> CvContext<T> for opencv::Result<T> {
    fn cv(self, context: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|source| Error::OpenCv {
            context: context(),
            source,
        })
    }
}
