//! The engine's layers (ARCHITECTURE.md) as the code has them: every module of `src/` lives in
//! a layer folder, and a module names only modules of its own layer or of the layers the
//! picture puts below it. The test reads the sources, finds every `crate::…` path outside
//! comments and test modules, and fails on an arrow the picture does not allow and on any circle
//! of imports between modules. It also keeps files and the terminal out of the numeric layers.
//!
//! Why a test rather than separate crates: the layers share one public API
//! (`photostereo::model::capture::Capture`, …) that the command line, the Python binding and
//! the examples use, and a test states the whole picture, including the arrows between the
//! middle layers (solve and geometry side by side, calibrate and scene above them), which a
//! split into crates would only approximate.
//!
//! The picture, bottom up:
//!
//! ```text
//! app        run driver, compare
//! io         formats, layouts, figures, output folders, the viewer page
//! method     engine, recursive driver, report values
//! calibrate  scene          (side by side)
//! solve      geometry       (side by side)
//! model      images, lights, light model, capture, sample store, memory plan
//! base       error, progress, rng, statistics, the machine, numbers
//! ```

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each layer and the layers it may name (besides itself).
const ALLOWED: [(&str, &[&str]); 9] = [
    ("base", &[]),
    ("model", &["base"]),
    ("solve", &["model", "base"]),
    ("geometry", &["model", "base"]),
    ("calibrate", &["solve", "geometry", "model", "base"]),
    ("scene", &["solve", "geometry", "model", "base"]),
    (
        "method",
        &["calibrate", "scene", "solve", "geometry", "model", "base"],
    ),
    (
        "io",
        &[
            "method",
            "calibrate",
            "scene",
            "solve",
            "geometry",
            "model",
            "base",
        ],
    ),
    (
        "app",
        &[
            "io",
            "method",
            "calibrate",
            "scene",
            "solve",
            "geometry",
            "model",
            "base",
        ],
    ),
];

/// Upward arrows the picture tolerates, with the reason: none.
const TOLERATED: [(&str, &str, &str); 0] = [];

/// Layers whose modules hold no file and print nothing, and the files that may still touch the
/// file system, with the reason.
const NO_FILES: [&str; 7] = [
    "base",
    "model",
    "solve",
    "geometry",
    "calibrate",
    "scene",
    "method",
];
const FILE_EXCEPTIONS: [(&str, &str); 2] = [
    (
        "base/machine.rs",
        "reads /proc and the cgroup's files for the memory available",
    ),
    (
        "model/store.rs",
        "the sample store's anonymous spill file when a capture exceeds the memory budget",
    ),
];

/// Layers that are one module each (their submodules are internal).
const SINGLE_MODULE: [&str; 2] = ["calibrate", "scene"];

fn src() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/src"))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module a source file belongs to (`layer::module`, or the layer for single-module
/// layers); `None` for the crate root and test-only files.
fn module_of(rel: &str) -> Option<String> {
    let parts: Vec<&str> = rel.trim_end_matches(".rs").split('/').collect();
    let layer = parts[0];
    if parts.len() == 1 {
        return None; // lib.rs, fixtures.rs
    }
    if SINGLE_MODULE.contains(&layer) || parts[1] == "mod" {
        return Some(layer.to_string());
    }
    Some(format!("{layer}::{}", parts[1]))
}

/// The code of a file without comments, string literals and `#[cfg(test)]` items.
fn code_of(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let b = text.as_bytes();
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            i = text[i..].find("*/").map_or(b.len(), |j| i + j + 2);
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else {
            out.push(b[i] as char);
            i += 1;
        }
    }
    // Drop every item behind #[cfg(test)] (a test module or function): up to its braces' end.
    while let Some(at) = out.find("#[cfg(test)]") {
        let open = out[at..].find('{').map(|j| at + j);
        let semi = out[at..].find(';').map(|j| at + j);
        let end = match (open, semi) {
            (Some(o), Some(s)) if s < o => s + 1,
            (Some(o), _) => {
                let mut depth = 0;
                let mut end = out.len();
                for (j, c) in out[o..].char_indices() {
                    match c {
                        '{' => depth += 1,
                        '}' => {
                            depth -= 1;
                            if depth == 0 {
                                end = o + j + 1;
                                break;
                            }
                        }
                        _ => {}
                    }
                }
                end
            }
            (None, Some(s)) => s + 1,
            (None, None) => out.len(),
        };
        out.replace_range(at..end, "");
    }
    out
}

/// The modules a file's code names through `crate::` paths, grouped imports included, and
/// through `super::` from a layer's top-level module.
fn named_modules(code: &str, own_layer: &str, rel: &str, layers: &[&str]) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    let module = |path: &[&str]| -> Option<String> {
        let layer = *path.first()?;
        if !layers.contains(&layer) {
            return None;
        }
        if SINGLE_MODULE.contains(&layer) {
            return Some(layer.to_string());
        }
        path.get(1)
            .filter(|m| m.chars().next().is_some_and(|c| c.is_ascii_lowercase()))
            .map(|m| format!("{layer}::{m}"))
    };
    // Expand `prefix::{a, b::c, d::{e}}` into paths, recursively.
    fn expand(prefix: &str, body: &str, out: &mut Vec<String>) {
        let mut depth = 0;
        let mut start = 0;
        let bytes = body.as_bytes();
        let mut parts = Vec::new();
        for (j, &c) in bytes.iter().enumerate() {
            match c {
                b'{' => depth += 1,
                b'}' => depth -= 1,
                b',' if depth == 0 => {
                    parts.push(&body[start..j]);
                    start = j + 1;
                }
                _ => {}
            }
        }
        parts.push(&body[start..]);
        for p in parts {
            let p = p.trim();
            if p.is_empty() {
                continue;
            }
            match p.find("::{") {
                Some(k) if p.ends_with('}') => expand(
                    &format!("{prefix}{}::", &p[..k]),
                    &p[k + 3..p.len() - 1],
                    out,
                ),
                _ => out.push(format!("{prefix}{p}")),
            }
        }
    }
    let mut paths = Vec::new();
    let mut rest = code;
    while let Some(at) = rest.find("crate::") {
        let tail = &rest[at + 7..];
        let end = tail
            .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':' || c == '{'))
            .unwrap_or(tail.len());
        let head = &tail[..end];
        if let Some(k) = head.find('{') {
            // A grouped import: read to the matching brace.
            let open = k;
            let mut depth = 0;
            let mut close = tail.len();
            for (j, c) in tail[open..].char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' => {
                        depth -= 1;
                        if depth == 0 {
                            close = open + j;
                            break;
                        }
                    }
                    _ => {}
                }
            }
            expand(&tail[..open], &tail[open + 1..close], &mut paths);
        } else {
            paths.push(head.to_string());
        }
        rest = &rest[at + 7..];
    }
    for p in &paths {
        let parts: Vec<&str> = p.split("::").filter(|s| !s.is_empty()).collect();
        if let Some(m) = module(&parts) {
            found.insert(m);
        }
    }
    // `super::x` in a layer's own modules (`L/m.rs`, `L/m/mod.rs`: module `L::m`, whose parent
    // is the layer) names a sibling module of the layer; deeper, it stays inside the module.
    let depth = rel.matches('/').count();
    let top_level =
        (depth == 1 && !rel.ends_with("/mod.rs")) || (depth == 2 && rel.ends_with("/mod.rs"));
    if top_level && !SINGLE_MODULE.contains(&own_layer) {
        let mut rest = code;
        while let Some(at) = rest.find("super::") {
            let tail = &rest[at + 7..];
            let name: String = tail
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() && name.chars().next().unwrap().is_ascii_lowercase() {
                found.insert(format!("{own_layer}::{name}"));
            }
            rest = tail;
        }
    }
    found
}

struct Graph {
    /// module → (module it names → files that name it)
    edges: BTreeMap<String, BTreeMap<String, BTreeSet<String>>>,
}

fn graph() -> Graph {
    let layers: Vec<&str> = ALLOWED.iter().map(|(l, _)| *l).collect();
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut edges: BTreeMap<String, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for f in files {
        let rel = f
            .strip_prefix(src())
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let layer = rel.split('/').next().unwrap().to_string();
        if !rel.contains('/') {
            continue;
        }
        assert!(
            layers.contains(&layer.as_str()),
            "{rel}: every module lives in a layer folder ({layers:?})"
        );
        if rel.ends_with("/tests.rs") {
            continue; // a module's unit tests
        }
        let Some(module) = module_of(&rel) else {
            continue;
        };
        let code = code_of(&std::fs::read_to_string(&f).unwrap());
        let entry = edges.entry(module.clone()).or_default();
        for named in named_modules(&code, &layer, &rel, &layers) {
            if named != module {
                entry.entry(named).or_default().insert(rel.clone());
            }
        }
    }
    Graph { edges }
}

fn layer(module: &str) -> &str {
    module.split("::").next().unwrap()
}

#[test]
fn modules_name_only_their_own_layer_or_the_layers_below() {
    let g = graph();
    let allowed: BTreeMap<&str, &[&str]> = ALLOWED.into_iter().collect();
    let mut bad = Vec::new();
    for (from, tos) in &g.edges {
        for (to, files) in tos {
            let (lf, lt) = (layer(from), layer(to));
            if lf == lt || allowed[lf].contains(&lt) {
                continue;
            }
            if TOLERATED.iter().any(|(a, b, _)| *a == from && *b == to) {
                continue;
            }
            bad.push(format!("{from} -> {to} (in {files:?})"));
        }
    }
    assert!(
        bad.is_empty(),
        "arrows the picture does not allow:\n{}",
        bad.join("\n")
    );
    // The test sees the imports at all: the engine names the solvers, io names the model.
    assert!(g.edges["method::engine"].contains_key("solve::detect"));
    assert!(g.edges["io::layouts"].contains_key("model::capture"));
}

#[test]
fn no_circle_of_imports_between_modules() {
    let g = graph();
    // Tarjan's strongly connected components, iteratively over the sorted modules.
    let nodes: Vec<&String> = g.edges.keys().collect();
    let index_of: BTreeMap<&str, usize> = nodes
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i))
        .collect();
    let succ: Vec<Vec<usize>> = nodes
        .iter()
        .map(|n| {
            g.edges[*n]
                .keys()
                .filter_map(|t| index_of.get(t.as_str()).copied())
                .collect()
        })
        .collect();
    let n = nodes.len();
    let (mut index, mut low, mut on) = (vec![usize::MAX; n], vec![0; n], vec![false; n]);
    let (mut stack, mut next, mut circles) = (Vec::new(), 0, Vec::new());
    for root in 0..n {
        if index[root] != usize::MAX {
            continue;
        }
        let mut work = vec![(root, 0usize)];
        while let Some(&mut (v, ref mut i)) = work.last_mut() {
            if *i == 0 {
                index[v] = next;
                low[v] = next;
                next += 1;
                stack.push(v);
                on[v] = true;
            }
            if *i < succ[v].len() {
                let w = succ[v][*i];
                *i += 1;
                if index[w] == usize::MAX {
                    work.push((w, 0));
                } else if on[w] {
                    low[v] = low[v].min(index[w]);
                }
                continue;
            }
            work.pop();
            if let Some(&(u, _)) = work.last() {
                low[u] = low[u].min(low[v]);
            }
            if low[v] == index[v] {
                let mut comp = Vec::new();
                loop {
                    let w = stack.pop().unwrap();
                    on[w] = false;
                    comp.push(nodes[w].clone());
                    if w == v {
                        break;
                    }
                }
                if comp.len() > 1 {
                    comp.sort();
                    circles.push(comp);
                }
            }
        }
    }
    assert!(
        circles.is_empty(),
        "modules that import each other: {circles:?}"
    );
}

#[test]
fn the_numeric_layers_hold_no_files_and_print_nothing() {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut bad = Vec::new();
    for f in files {
        let rel = f
            .strip_prefix(src())
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let code = code_of(&std::fs::read_to_string(&f).unwrap());
        for p in ["println!", "eprintln!", "print!(", "eprint!(", "dbg!("] {
            if code.contains(p) {
                bad.push(format!("{rel}: {p} (the library prints nothing)"));
            }
        }
        let layer = rel.split('/').next().unwrap();
        if NO_FILES.contains(&layer)
            && !FILE_EXCEPTIONS.iter().any(|(f, _)| *f == rel)
            && (code.contains("std::fs") || code.contains("File::"))
        {
            bad.push(format!("{rel}: touches files in the {layer} layer"));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// The reader itself: grouped and nested imports, comments, strings and test modules.
#[test]
fn the_import_reader_reads_what_rust_means() {
    let code = code_of(
        "use crate::{model::{capture::Capture, lights}, base::error::Error};\n\
         // use crate::io::export;\n\
         let s = \"crate::app::pipeline\";\n\
         fn f() { crate::solve::lambert::channel_mean(); }\n\
         #[cfg(test)]\nmod tests { use crate::io::figure; }\n",
    );
    let layers: Vec<&str> = ALLOWED.iter().map(|(l, _)| *l).collect();
    let found = named_modules(&code, "method", "method/engine.rs", &layers);
    let want: BTreeSet<String> = [
        "model::capture",
        "model::lights",
        "base::error",
        "solve::lambert",
    ]
    .map(String::from)
    .into_iter()
    .collect();
    assert_eq!(found, want);
    let inside = named_modules(
        "use super::detect::Detection;",
        "solve",
        "solve/estimate/least_squares.rs",
        &layers,
    );
    assert!(inside.is_empty(), "super:: inside a module stays inside it");
    let sibling = named_modules(
        "use super::detect::Detection;",
        "solve",
        "solve/estimate/mod.rs",
        &layers,
    );
    assert!(sibling.contains("solve::detect"));
    let sibling = named_modules(
        "use super::detect::Detection;",
        "solve",
        "solve/lambert.rs",
        &layers,
    );
    assert!(sibling.contains("solve::detect"));
}
