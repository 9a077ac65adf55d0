//! The library's layers point one way: no import cycle between its top-level modules; the file
//! formats (project, workflow, manifest, the step list and the parameters they record) are plain
//! data that reach no GPU, kernel or analysis code; clap (the command line) only in the binary
//! (`src/main.rs` and the modules it declares).
//! Read from the sources, the way a reviewer reads `use crate::…` lines.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Source files of the binary (everything else under src/ is the library).
const BINARY: [&str; 2] = ["main.rs", "cli.rs"];

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The code of a Rust file without `//` comments (doc comments name modules in prose).
fn code(text: &str) -> String {
    text.lines()
        .map(|l| match l.find("//") {
            Some(i) if !l[..i].contains('"') => &l[..i],
            _ => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn ident_at(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// Top-level modules named by `crate::name` paths and `use crate::{a, b::c}` groups.
fn imports(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in code.match_indices("crate::") {
        let rest = &code[i + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            // Names at the group's top level: after `{` and after each depth-0 comma.
            let mut depth = 0;
            let mut start = true;
            for (j, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => start = true,
                    c if c.is_whitespace() => {}
                    _ if start && depth == 0 => {
                        out.insert(ident_at(&group[j..]).to_string());
                        start = false;
                    }
                    _ => {}
                }
            }
        } else {
            out.insert(ident_at(rest).to_string());
        }
    }
    out
}

/// Module graph: top-level module -> top-level modules it imports.
fn graph() -> (BTreeMap<String, BTreeSet<String>>, Vec<String>) {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut clap_in_library = Vec::new();
    for f in files {
        let rel = f.strip_prefix(&src).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        if BINARY.contains(&first.as_ref()) || first == "lib.rs" {
            continue;
        }
        let module = first.trim_end_matches(".rs").to_string();
        let text = code(&std::fs::read_to_string(&f).unwrap());
        if text.contains("clap::") || text.contains("use clap") {
            clap_in_library.push(rel.display().to_string());
        }
        let entry = g.entry(module.clone()).or_default();
        for m in imports(&text) {
            // `Error`/`Result` are re-exported at the crate root from `error`.
            let m = match m.as_str() {
                "Error" | "Result" => "error".to_string(),
                _ => m,
            };
            if m != module && !m.is_empty() {
                entry.insert(m);
            }
        }
    }
    (g, clap_in_library)
}

/// One cycle through `start`, if any (depth-first search).
fn cycle_from(g: &BTreeMap<String, BTreeSet<String>>, start: &str) -> Option<Vec<String>> {
    fn walk(
        g: &BTreeMap<String, BTreeSet<String>>,
        at: &str,
        start: &str,
        path: &mut Vec<String>,
        seen: &mut BTreeSet<String>,
    ) -> bool {
        for next in g.get(at).into_iter().flatten() {
            if next == start {
                path.push(next.clone());
                return true;
            }
            if seen.insert(next.clone()) {
                path.push(next.clone());
                if walk(g, next, start, path, seen) {
                    return true;
                }
                path.pop();
            }
        }
        false
    }
    let mut path = vec![start.to_string()];
    walk(g, start, start, &mut path, &mut BTreeSet::new()).then_some(path)
}

/// The library's layers, top to bottom, as docs/architecture.md draws them: a module may
/// import modules of its own layer or below, never above.
const LAYERS: [(&str, &[&str]); 4] = [
    (
        "commands",
        &[
            "review",
            "select",
            "export",
            "batch",
            "colmap",
            "reconstruct",
            "eval",
            "report",
            "bench",
            "bench_pipeline",
            "flow",
            "info",
        ],
    ),
    (
        "engines",
        &[
            "analysis", "kernels", "gpu", "segment", "encode", "geotag", "native", "rig",
        ],
    ),
    (
        "formats",
        &[
            "project",
            "workflow",
            "manifest",
            "model_desc",
            "steps",
            "params",
            "sparse",
            "flo",
        ],
    ),
    (
        "base",
        &[
            "source",
            "error",
            "output",
            "fsutil",
            "tomlfile",
            "progress",
            "synthetic",
            "names",
            "numbers",
            "equirect",
            "embedding_file",
        ],
    ),
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, ms)| ms.contains(&module))
}

/// Every module `from` imports, directly or through others.
fn reachable(g: &BTreeMap<String, BTreeSet<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut todo = vec![from.to_string()];
    while let Some(m) = todo.pop() {
        for next in g.get(&m).into_iter().flatten() {
            if seen.insert(next.clone()) {
                todo.push(next.clone());
            }
        }
    }
    seen
}

#[test]
fn the_import_graph_finds_groups_and_paths() {
    let got = imports("use crate::{a::X, b, c::{d, e}};\nfn f() { crate::g::h(); }");
    let want: BTreeSet<String> = ["a", "b", "c", "g"].iter().map(|s| s.to_string()).collect();
    assert_eq!(got, want);
    let mut g = BTreeMap::new();
    g.insert("a".to_string(), BTreeSet::from(["b".to_string()]));
    g.insert("b".to_string(), BTreeSet::from(["a".to_string()]));
    assert_eq!(
        cycle_from(&g, "a"),
        Some(vec!["a".into(), "b".into(), "a".into()])
    );
}

#[test]
fn library_layers_point_down_without_cycles_and_clap_stays_in_the_binary() {
    let (g, clap_in_library) = graph();
    assert!(g.len() > 20, "read too few modules: {:?}", g.keys());
    assert!(
        g["select"].contains("analysis"),
        "the graph misses a known edge"
    );
    let cycles: Vec<String> = g
        .keys()
        .filter_map(|m| cycle_from(&g, m))
        .map(|c| c.join(" -> "))
        .collect();
    assert!(cycles.is_empty(), "import cycles:\n{}", cycles.join("\n"));
    let mut upward = Vec::new();
    for (m, deps) in &g {
        let Some(at) = layer_of(m) else {
            upward.push(format!(
                "{m} is in no layer (add it to LAYERS and docs/architecture.md)"
            ));
            continue;
        };
        for d in deps {
            match layer_of(d) {
                Some(l) if l < at => upward.push(format!(
                    "{m} ({}) imports {d} ({})",
                    LAYERS[at].0, LAYERS[l].0
                )),
                Some(_) => {}
                None => upward.push(format!("{d} is in no layer")),
            }
        }
    }
    assert!(
        upward.is_empty(),
        "imports pointing up:\n{}",
        upward.join("\n")
    );
    for format in ["project", "workflow", "manifest", "steps", "params"] {
        let reached = reachable(&g, format);
        let engines: Vec<&str> = ["gpu", "kernels", "analysis", "select", "export"]
            .into_iter()
            .filter(|m| reached.contains(*m))
            .collect();
        assert!(
            engines.is_empty(),
            "the file format `{format}` reaches engine code {engines:?} (it reaches {reached:?})"
        );
    }
    assert!(
        clap_in_library.is_empty(),
        "clap used by library files: {clap_in_library:?}"
    );
}
