//! Reads TOML files (workflows, model descriptions) so that every error names the file, the line
//! and the key: syntax and type errors from the parser, and semantic errors found afterwards.

use crate::error::{Error, Result};
use serde::de::DeserializeOwned;
use std::path::{Path, PathBuf};

/// A parsed TOML file that can still point at its own lines.
pub struct TomlFile<T> {
    /// The parsed content.
    pub value: T,
    path: PathBuf,
    what: &'static str,
    doc: Option<toml_edit::ImDocument<String>>,
    text: String,
}

/// Reads and deserializes `path`; `what` names the kind of file in errors ("workflow").
pub fn read<T: DeserializeOwned>(path: &Path, what: &'static str) -> Result<TomlFile<T>> {
    let text = crate::output::read_text(path)?;
    parse(path, what, text)
}

/// Deserializes `text` as if read from `path`.
pub fn parse<T: DeserializeOwned>(
    path: &Path,
    what: &'static str,
    text: String,
) -> Result<TomlFile<T>> {
    let doc = toml_edit::ImDocument::parse(text.clone()).ok();
    let de = toml::Deserializer::new(&text);
    let value: T = serde_path_to_error::deserialize(de).map_err(|e| {
        let field = e.path().to_string();
        let inner = e.into_inner();
        let field = if field == "." { String::new() } else { field };
        // A missing key has no span of its own: name it (under its table) instead.
        let message = inner.message().trim().to_string();
        let field = match message
            .strip_prefix("missing field `")
            .and_then(|r| r.split('`').next())
        {
            Some(key) if field.is_empty() => key.to_string(),
            Some(key) => format!("{field}.{key}"),
            None => field,
        };
        // Errors inside internally tagged tables carry no span: use the key's own line.
        let line = inner
            .span()
            .map(|s| line_of(&text, s.start))
            .or_else(|| doc.as_ref().and_then(|d| key_line(d, &text, &field)));
        Error::file(path, line, what, field, message)
    })?;
    Ok(TomlFile {
        value,
        path: path.to_path_buf(),
        what,
        doc,
        text,
    })
}

impl<T> TomlFile<T> {
    /// The file's text as read.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The file it was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// An error about the key at `field` (dotted, with `[i]` for array elements, e.g.
    /// `sample[2].fps`), pointing at its line when the key is present in the file.
    pub fn error(&self, field: &str, msg: impl Into<String>) -> Error {
        Error::file(&self.path, self.line_of_key(field), self.what, field, msg)
    }

    /// Line (1-based) of the key at `field`, or of its nearest present parent.
    pub fn line_of_key(&self, field: &str) -> Option<usize> {
        key_line(self.doc.as_ref()?, &self.text, field)
    }
}

/// An error about the key at `field` of the TOML `text` read from `path` (as
/// [`TomlFile::error`], for a file no longer held parsed).
pub fn error_in(
    path: &Path,
    what: &'static str,
    text: &str,
    field: &str,
    msg: impl Into<String>,
) -> Error {
    let line = toml_edit::ImDocument::parse(text.to_string())
        .ok()
        .and_then(|d| key_line(&d, text, field));
    Error::file(path, line, what, field, msg)
}

fn key_line(doc: &toml_edit::ImDocument<String>, text: &str, field: &str) -> Option<usize> {
    let mut item: &toml_edit::Item = doc.as_item();
    let mut best = None;
    for seg in split_path(field) {
        let next = match seg {
            Seg::Key(k) => item.get(k),
            Seg::Index(i) => item.get(i),
        };
        let Some(next) = next else { break };
        item = next;
        if let Some(span) = item.span() {
            best = Some(line_of(text, span.start));
        }
    }
    best
}

enum Seg<'a> {
    Key(&'a str),
    Index(usize),
}

fn split_path(field: &str) -> Vec<Seg<'_>> {
    let mut out = Vec::new();
    for part in field.split('.').filter(|p| !p.is_empty()) {
        let (key, rest) = part.split_once('[').unwrap_or((part, ""));
        if !key.is_empty() {
            out.push(Seg::Key(key));
        }
        for idx in rest.split('[') {
            if let Ok(i) = idx.trim_end_matches(']').parse::<usize>() {
                out.push(Seg::Index(i));
            }
        }
    }
    out
}

fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    struct Doc {
        #[allow(dead_code)]
        a: u32,
        #[allow(dead_code)]
        b: Vec<Inner>,
    }
    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    struct Inner {
        #[allow(dead_code)]
        x: f64,
    }

    #[test]
    fn errors_name_line_and_key() {
        let p = Path::new("w.toml");
        let text = "a = 1\n\n[[b]]\nx = 1.0\n[[b]]\nx = \"no\"\n";
        let e = parse::<Doc>(p, "workflow", text.into())
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            e.starts_with("w.toml:6: invalid workflow at `b[1].x`"),
            "{e}"
        );

        let ok = parse::<Doc>(
            p,
            "workflow",
            "a = 1\n[[b]]\nx = 2.0\n[[b]]\nx = 3.0\n".into(),
        )
        .map_err(|e| e.to_string())
        .unwrap();
        assert_eq!(ok.line_of_key("b[1].x"), Some(5));
        assert_eq!(ok.line_of_key("a"), Some(1));
        let e = ok.error("b[0].x", "too small").to_string();
        assert_eq!(e, "w.toml:3: invalid workflow at `b[0].x`: too small");
    }
}
