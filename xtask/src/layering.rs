//! `cargo xtask layering`: no import cycle between the top-level modules of any crate of the
//! root workspace. Cargo already refuses cycles between crates; inside a crate nothing does,
//! so this reads each crate's sources as text (not a parser: a `crate::x` in a string counts
//! too, which errs on the safe side) and looks for strongly connected modules.
//!
//! Edges: a top-level module `a` depends on `b` when a file of `a` names `crate::b` (also in a
//! `crate::{b, ...}` group), or `crate::Item` where the root re-exports `Item` from `b`, or,
//! in `a`'s own top-level file, `super::b`. Unit tests (`#[cfg(test)] mod tests`) and comment
//! lines are left out: tests may use anything of their crate, and a doc link imports nothing.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// One crate's top-level modules and the edges between them.
#[derive(Debug, Default)]
pub struct ModuleGraph {
    /// Module name to the modules it uses.
    pub edges: BTreeMap<String, BTreeSet<String>>,
}

impl ModuleGraph {
    /// The groups of two or more modules that import each other (strongly connected
    /// components), each sorted.
    pub fn cycles(&self) -> Vec<Vec<String>> {
        let names: Vec<&String> = self.edges.keys().collect();
        let reach = |from: &String| -> BTreeSet<String> {
            let mut seen = BTreeSet::new();
            let mut stack = vec![from.clone()];
            while let Some(m) = stack.pop() {
                for next in self.edges.get(&m).into_iter().flatten() {
                    if seen.insert(next.clone()) {
                        stack.push(next.clone());
                    }
                }
            }
            seen
        };
        let reachable: BTreeMap<&String, BTreeSet<String>> = names.iter().map(|n| (*n, reach(n))).collect();
        let mut done = BTreeSet::new();
        let mut out = Vec::new();
        for n in &names {
            if done.contains(*n) {
                continue;
            }
            let group: Vec<String> = names
                .iter()
                .filter(|m| reachable[*n].contains(**m) && reachable[*m].contains(*n))
                .map(|m| (*m).clone())
                .collect();
            done.extend(group.iter().cloned());
            if group.len() > 1 {
                out.push(group);
            }
        }
        out
    }
}

/// The source of `path` without its unit tests and comment lines (a doc link is not an import).
fn source_without_tests(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let code = match text.find("#[cfg(test)]\nmod tests") {
        Some(at) => &text[..at],
        None => &text,
    };
    code.lines().filter(|l| !l.trim_start().starts_with("//")).collect::<Vec<_>>().join("\n")
}

/// Identifiers `name` follows in `text`, e.g. `crate::` -> the `x` of `crate::x` and of
/// every entry of `crate::{x, y::z}`.
fn names_after(text: &str, prefix: &str) -> BTreeSet<String> {
    let ident = |s: &str| -> String { s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect() };
    let mut out = BTreeSet::new();
    for (at, _) in text.match_indices(prefix) {
        // `$crate::`, `sts_x::crate::` etc. are not ours.
        let before = text[..at].chars().next_back();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '$' || c == ':') {
            continue;
        }
        let rest = &text[at + prefix.len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let end = group.find('}').unwrap_or(group.len());
            out.extend(group[..end].split(',').map(|entry| ident(entry.trim())).filter(|s| !s.is_empty()));
        } else {
            let name = ident(rest);
            if !name.is_empty() {
                out.insert(name);
            }
        }
    }
    out
}

/// `.rs` files under `dir`, sorted.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = entry.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The module graph of the crate whose root file is `root_file` (`src/lib.rs` or `src/main.rs`).
pub fn module_graph(root_file: &Path) -> ModuleGraph {
    let src = root_file.parent().unwrap_or(Path::new("."));
    let root = source_without_tests(root_file);
    // Top-level modules: `mod x;` declarations of the root.
    let modules: BTreeSet<String> = root
        .lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let l = l.strip_prefix("pub ").or_else(|| l.strip_prefix("pub(crate) ")).unwrap_or(l);
            l.strip_prefix("mod ").and_then(|r| r.strip_suffix(';')).map(str::to_string)
        })
        .collect();
    // Items the root re-exports from a module: `pub use m::{A, B}` / `pub use m::A` / `pub use m::*`.
    let mut owner: BTreeMap<String, String> = BTreeMap::new();
    for line in root.lines().filter_map(|l| l.trim().strip_prefix("pub use ")) {
        let module: String = line.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        if !modules.contains(&module) {
            continue;
        }
        for item in names_after(&format!(" {line}"), &format!("{module}::")) {
            owner.insert(item, module.clone());
        }
        if line.contains("::*") {
            for file in module_files(src, &module) {
                for item in public_items(&source_without_tests(&file)) {
                    owner.entry(item).or_insert_with(|| module.clone());
                }
            }
        }
    }
    let mut graph = ModuleGraph::default();
    for module in &modules {
        let mut uses = BTreeSet::new();
        for file in module_files(src, module) {
            let text = source_without_tests(&file);
            let mut named = names_after(&text, "crate::");
            let top_file = file == src.join(format!("{module}.rs")) || file == src.join(module).join("mod.rs");
            if top_file {
                named.extend(names_after(&text, "super::"));
            }
            for name in named {
                let target = if modules.contains(&name) { Some(name) } else { owner.get(&name).cloned() };
                if let Some(t) = target.filter(|t| t != module) {
                    uses.insert(t);
                }
            }
        }
        graph.edges.insert(module.clone(), uses);
    }
    graph
}

/// The files of top-level module `module`: `src/module.rs` and everything under `src/module/`.
fn module_files(src: &Path, module: &str) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let file = src.join(format!("{module}.rs"));
    if file.is_file() {
        files.push(file);
    }
    let dir = src.join(module);
    if dir.is_dir() {
        files.extend(rust_files(&dir));
    }
    files
}

/// Names of the `pub` items declared at the start of a line in `text`.
fn public_items(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for line in text.lines() {
        let Some(rest) = line.strip_prefix("pub ") else { continue };
        for kind in ["fn ", "struct ", "enum ", "trait ", "const ", "static ", "type ", "mod "] {
            if let Some(name) = rest.strip_prefix(kind) {
                out.insert(name.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect());
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_a_cycle_through_a_reexport_and_ignores_tests() {
        let dir = std::env::temp_dir().join(format!("xtask-layering-{}", std::process::id()));
        let src = dir.join("src");
        std::fs::create_dir_all(src.join("b")).unwrap();
        std::fs::write(src.join("lib.rs"), "mod a;\npub mod b;\nmod c;\npub use a::*;\n").unwrap();
        std::fs::write(src.join("a.rs"), "pub fn f() {}\nuse crate::b::g;\n").unwrap();
        std::fs::write(src.join("b").join("mod.rs"), "mod inner;\npub fn g() {}\n").unwrap();
        std::fs::write(src.join("b").join("inner.rs"), "use crate::{f, c::h};\n").unwrap();
        std::fs::write(src.join("c.rs"), "pub fn h() {}\n#[cfg(test)]\nmod tests {\n use crate::a::f;\n}\n").unwrap();
        let graph = module_graph(&src.join("lib.rs"));
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(graph.edges["a"], BTreeSet::from(["b".to_string()]));
        assert_eq!(graph.edges["b"], BTreeSet::from(["a".to_string(), "c".to_string()]));
        assert!(graph.edges["c"].is_empty(), "a unit test's import is not an edge");
        assert_eq!(graph.cycles(), vec![vec!["a".to_string(), "b".to_string()]]);
    }
}
