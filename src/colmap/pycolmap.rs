//! The pycolmap engine of `keyframer colmap` (`--engine pycolmap`): a recent COLMAP from PyPI
//! that maps a rig export as a rig. Finds a Python with pycolmap (`KEYFRAMER_PYTHON`, else
//! `pycolmap/bin/python` in the folder above keyframer's executable, which `scripts/setup.sh`
//! makes as `target/pycolmap`, else `python3` on PATH) and says what is missing when none
//! imports it; the driver keyframer ships (`pycolmap_stages.py`, written into the workspace)
//! serves a run's or a reconstruct loop's stages from one process (`serve`), each stage's
//! output in `logs/<stage>.log`.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Environment variable naming a Python interpreter that imports pycolmap.
pub const PYTHON_ENV: &str = "KEYFRAMER_PYTHON";
/// The driver's file name in the workspace (one of keyframer's own files there).
pub const DRIVER: &str = "pycolmap_stages.py";
/// The driver's source.
pub const DRIVER_SOURCE: &str = include_str!("pycolmap_stages.py");
/// The pycolmap release keyframer is tested with (`scripts/setup.sh` installs it).
pub const TESTED: &str = "4.2.1";
/// The oldest major version whose API the driver uses (rigs, `FeatureExtractionOptions`).
const MIN_MAJOR: u32 = 4;

pub use crate::sparse::Engine;

/// The pycolmap used: its interpreter and version.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pycolmap {
    /// The Python interpreter that imports it.
    pub python: PathBuf,
    /// `pycolmap.__version__`.
    pub version: String,
}

/// How to get pycolmap, for error messages and hints.
pub fn install_hint() -> String {
    format!(
        "scripts/setup.sh installs it into target/pycolmap (a venv with `pip install pycolmap=={TESTED}`); \
         or set {PYTHON_ENV} to a Python that imports pycolmap {TESTED}"
    )
}

/// Finds pycolmap: `KEYFRAMER_PYTHON` (which must import it), else `pycolmap/bin/python` in the
/// folder above keyframer's executable, else `python3` on PATH; the error names what each
/// candidate lacked and how to install it.
pub fn locate() -> Result<Pycolmap> {
    if let Some(p) = std::env::var_os(PYTHON_ENV) {
        let p = PathBuf::from(p);
        return probe(&p).map_err(|why| {
            Error::Colmap(format!(
                "{PYTHON_ENV}={}: {why}; {}",
                p.display(),
                install_hint()
            ))
        });
    }
    let mut tried = Vec::new();
    let beside = std::env::current_exe()
        .ok()
        .and_then(|e| Some(e.parent()?.parent()?.join("pycolmap/bin/python")));
    for candidate in beside
        .into_iter()
        .chain(crate::fsutil::find_on_path("python3"))
    {
        match probe(&candidate) {
            Ok(found) => return Ok(found),
            Err(why) => tried.push(format!("{}: {why}", candidate.display())),
        }
    }
    if tried.is_empty() {
        tried.push("no python3 on PATH".into());
    }
    Err(Error::Colmap(format!(
        "pycolmap not found ({}); {}",
        tried.join("; "),
        install_hint()
    )))
}

/// The pycolmap that `python` imports, or why it does not do.
fn probe(python: &Path) -> std::result::Result<Pycolmap, String> {
    if !python.is_file() {
        return Err("no such file".into());
    }
    let out = Command::new(python)
        .args(["-c", "import pycolmap; print(pycolmap.__version__)"])
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("cannot run: {e}"))?;
    if !out.status.success() {
        return Err("does not import pycolmap".into());
    }
    let version = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let major = version
        .split('.')
        .next()
        .and_then(|m| m.parse::<u32>().ok());
    if major.is_none_or(|m| m < MIN_MAJOR) {
        return Err(format!(
            "has pycolmap {version}; keyframer's driver needs pycolmap {MIN_MAJOR}.x or later"
        ));
    }
    Ok(Pycolmap {
        python: python.to_path_buf(),
        version,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::names::Names;

    #[test]
    fn a_missing_interpreter_is_named() {
        let why = probe(Path::new("/nonexistent/python")).unwrap_err();
        assert_eq!(why, "no such file");
    }

    #[test]
    fn engines_have_names() {
        assert_eq!(Engine::from_name("pycolmap"), Ok(Engine::Pycolmap));
        assert_eq!(Engine::Auto.name(), "auto");
        assert!(Engine::from_name("glomap").is_err());
    }

    #[test]
    fn the_driver_has_every_stage_keyframer_runs() {
        for stage in [
            "feature_extractor",
            "rig_configurator",
            "matches_importer",
            "sequential_matcher",
            "exhaustive_matcher",
            "mapper",
            "global_mapper",
        ] {
            assert!(
                DRIVER_SOURCE.contains(&format!("sub.add_parser(\"{stage}\")")),
                "{stage}"
            );
        }
    }
}
