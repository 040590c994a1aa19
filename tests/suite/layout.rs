//! The layout's rules that a reader relies on (ARCHITECTURE.md,
//! "Invariants"): no import cycle between the library's files. A file
//! depends on another where it names it by a `crate::` or `super::` path
//! (doc comments too, as a link upward is a dependency a reader follows);
//! unit tests, after `#[cfg(test)]`, are left out, and so is a module's
//! `mod.rs` with its own children (it declares them).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("src") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The module path of a file under `src` (`scene/mod.rs` and `scene.rs`: `["scene"]`).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file
        .strip_prefix(src)
        .expect("under src")
        .with_extension("");
    let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into()).collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib") {
        parts.pop();
    }
    parts
}

/// The file holding the longest prefix of `path` that is a module.
fn file_of(src: &Path, path: &[String]) -> Option<PathBuf> {
    (1..=path.len()).rev().find_map(|k| {
        let base = path[..k].iter().fold(src.to_path_buf(), |p, s| p.join(s));
        [base.with_extension("rs"), base.join("mod.rs")]
            .into_iter()
            .find(|f| f.exists())
    })
}

/// The library's files and the files each names.
fn graph(src: &Path) -> BTreeMap<PathBuf, BTreeSet<PathBuf>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut graph = BTreeMap::new();
    for file in files.iter().filter(|f| !f.ends_with("main.rs")) {
        let text = std::fs::read_to_string(file).expect("read");
        let code = text.split("#[cfg(test)]").next().unwrap_or("");
        let here = module_of(src, file);
        let mut deps = BTreeSet::new();
        for (prefix, base) in [("crate::", Vec::new()), ("super::", parent(&here))] {
            for (at, _) in code.match_indices(prefix) {
                let before = code[..at].chars().next_back();
                if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
                    continue;
                }
                let rest: String = code[at + prefix.len()..]
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                    .collect();
                let mut path = base.clone();
                path.extend(rest.split("::").filter(|s| !s.is_empty()).map(String::from));
                for target in imports(&path, &code[at + prefix.len() + rest.len()..]) {
                    if let Some(f) = file_of(src, &target).filter(|f| f != file) {
                        deps.insert(f);
                    }
                }
            }
        }
        graph.insert(file.clone(), deps);
    }
    graph
}

/// `path`, or for `path::{a, b::c}` each of `path::a` and `path::b::c`.
fn imports(path: &[String], after: &str) -> Vec<Vec<String>> {
    let Some(group) = after.strip_prefix('{') else {
        return vec![path.to_vec()];
    };
    let inner = &group[..group.find('}').unwrap_or(group.len())];
    inner
        .split(',')
        .map(|item| {
            let mut p = path.to_vec();
            p.extend(
                item.split_whitespace()
                    .next()
                    .unwrap_or("")
                    .split("::")
                    .filter(|s| !s.is_empty() && *s != "self")
                    .map(String::from),
            );
            p
        })
        .collect()
}

/// The module `super` names from a file of module `here`.
fn parent(here: &[String]) -> Vec<String> {
    here[..here.len().saturating_sub(1)].to_vec()
}

/// The cycles: strongly connected sets of two files or more (Tarjan), less
/// a `mod.rs` with its own child.
fn cycles(graph: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    struct Walk<'g> {
        graph: &'g BTreeMap<PathBuf, BTreeSet<PathBuf>>,
        index: BTreeMap<&'g PathBuf, usize>,
        low: BTreeMap<&'g PathBuf, usize>,
        stack: Vec<&'g PathBuf>,
        found: Vec<Vec<PathBuf>>,
    }
    impl<'g> Walk<'g> {
        fn visit(&mut self, v: &'g PathBuf) {
            let n = self.index.len();
            self.index.insert(v, n);
            self.low.insert(v, n);
            self.stack.push(v);
            for w in self.graph.get(v).into_iter().flatten() {
                if !self.index.contains_key(w) {
                    self.visit(w);
                    self.low.insert(v, self.low[v].min(self.low[w]));
                } else if self.stack.contains(&w) {
                    self.low.insert(v, self.low[v].min(self.index[w]));
                }
            }
            if self.low[v] == self.index[v] {
                let mut set = Vec::new();
                while let Some(w) = self.stack.pop() {
                    set.push(w.clone());
                    if w == v {
                        break;
                    }
                }
                self.found.push(set);
            }
        }
    }
    let mut walk = Walk {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        found: Vec::new(),
    };
    for v in graph.keys() {
        if !walk.index.contains_key(v) {
            walk.visit(v);
        }
    }
    let parent_and_child = |c: &[PathBuf]| c.len() == 2 && c.iter().any(|f| f.ends_with("mod.rs"));
    walk.found
        .into_iter()
        .filter(|c| c.len() > 1 && !parent_and_child(c))
        .collect()
}

#[test]
fn no_import_cycle_between_the_librarys_files() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let found = cycles(&graph(&src));
    assert!(found.is_empty(), "import cycles: {found:#?}");
}

#[test]
fn the_cycle_check_finds_a_cycle() {
    // Two files that name each other, one through `super::`.
    let dir = tempfile::tempdir().expect("temp dir");
    let src = dir.path().join("src");
    std::fs::create_dir_all(src.join("scene")).expect("dirs");
    std::fs::write(src.join("lib.rs"), "pub mod scene;\n").expect("write");
    std::fs::write(src.join("scene/mod.rs"), "mod a;\nmod b;\n").expect("write");
    std::fs::write(src.join("scene/a.rs"), "use super::b::f;\n").expect("write");
    std::fs::write(
        src.join("scene/b.rs"),
        "use crate::scene::{a::g, mod_item};\n",
    )
    .expect("write");
    let found = cycles(&graph(&src));
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!(found[0].len(), 2, "{found:?}");
}

/// The library's files that name `crate_name` (`wgpu::`, `mpi::`) in code.
fn files_naming(crate_name: &str) -> Vec<String> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut naming: Vec<String> = files
        .iter()
        .filter(|f| {
            let text = std::fs::read_to_string(f).expect("read");
            text.lines()
                .filter(|l| !l.trim_start().starts_with("//"))
                .any(|l| l.contains(&format!("{crate_name}::")))
        })
        .map(|f| {
            f.strip_prefix(&src)
                .expect("under src")
                .display()
                .to_string()
        })
        .collect();
    naming.sort();
    naming
}

#[test]
fn only_gpu_uses_wgpu_and_only_comm_uses_mpi() {
    let wgpu = files_naming("wgpu");
    assert!(
        wgpu.iter().all(|f| f.starts_with("gpu/")),
        "wgpu outside src/gpu/: {wgpu:?}"
    );
    assert!(!wgpu.is_empty());
    assert_eq!(files_naming("mpi"), ["comm.rs"]);
}
