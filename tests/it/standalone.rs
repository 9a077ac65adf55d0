//! The repository stands alone: the model descriptions in `models/` name files inside it (set-up
//! puts the networks under `target/models/`), and no file of the product (README, docs, src,
//! models, scripts, workflows) refers to the folder beside it (`../shared`), which only the tests
//! may use for extra assets.

use std::path::{Component, Path, PathBuf};

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Whether `rel` (relative to the repository) stays inside it, read lexically.
fn inside(rel: &Path) -> bool {
    let mut depth = 0usize;
    rel.components().all(|c| match c {
        Component::Normal(_) => {
            depth += 1;
            true
        }
        Component::CurDir => true,
        Component::ParentDir if depth > 0 => {
            depth -= 1;
            true
        }
        _ => false,
    })
}

fn files_under(p: &Path, out: &mut Vec<PathBuf>) {
    if p.is_dir() {
        for e in std::fs::read_dir(p).unwrap() {
            files_under(&e.unwrap().path(), out);
        }
    } else {
        out.push(p.to_path_buf());
    }
}

#[test]
fn model_descriptions_name_files_inside_the_repository() {
    let mut descs = Vec::new();
    files_under(&repo().join("models"), &mut descs);
    descs.retain(|p| p.extension().is_some_and(|e| e == "toml"));
    assert!(descs.len() >= 3, "models/ holds the example descriptions");
    for d in descs {
        let v: toml::Table = toml::from_str(&std::fs::read_to_string(&d).unwrap()).unwrap();
        let named: Vec<&str> = ["model", "config", "classes_file", "colors_file"]
            .iter()
            .filter_map(|k| v.get(*k).and_then(|x| x.as_str()))
            .collect();
        assert!(!named.is_empty(), "{} names its network", d.display());
        for f in named {
            let rel = Path::new("models").join(f);
            assert!(
                inside(&rel),
                "{}: {f} is outside the repository",
                d.display()
            );
        }
    }
}

#[test]
fn the_product_refers_to_nothing_beside_the_repository() {
    let mut files = Vec::new();
    for p in ["README.md", "docs", "src", "models", "scripts", "workflows"] {
        files_under(&repo().join(p), &mut files);
    }
    let needle = b"../shared";
    let naming: Vec<String> = files
        .iter()
        .filter(|f| {
            let bytes = std::fs::read(f).unwrap();
            bytes.windows(needle.len()).any(|w| w == needle)
        })
        .map(|f| f.strip_prefix(repo()).unwrap().display().to_string())
        .collect();
    assert!(naming.is_empty(), "these files name ../shared: {naming:?}");
}
