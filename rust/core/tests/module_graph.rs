//! The core's modules form no cycle: each file is a node, each reference from
//! one file to an item of another an edge, and the graph must be acyclic so
//! that the crate reads bottom-up (docs/architecture.md, "Dependency order").
//!
//! What counts as an edge, read from the source text (comments stripped):
//! * `use crate::…`, `use super::…`, `use self::…` and relative `use child::…`
//!   anywhere outside test code, and `crate::…`/`super::…` paths written
//!   inline in code;
//! * a path naming an item a module re-exports (`pub use child::Item` in a
//!   `mod.rs`) points at the module that defines it, so going through a
//!   parent's re-exports hides nothing;
//! * a module declaring or re-exporting its own descendants is not an edge
//!   (a `mod.rs` listing its children is not a dependency on them), nor is a
//!   reference to itself.
//!
//! Test code is left out: `#[cfg(test)]` items and files under `tests/` or
//! named `tests.rs`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

type Module = Vec<String>;

/// Module path of a source file relative to `src/` (`lib.rs` is the root).
fn module_of(relative: &str) -> Module {
    let trimmed = relative.trim_end_matches(".rs");
    let mut parts: Vec<String> = trimmed.split('/').map(str::to_string).collect();
    if matches!(parts.last().map(String::as_str), Some("mod") | Some("lib")) {
        parts.pop();
    }
    parts
}

/// The source without comments, string literals' contents and
/// `#[cfg(test)]` items.
fn code_only(source: &str) -> String {
    let mut out = String::with_capacity(source.len());
    let bytes: Vec<char> = source.chars().collect();
    let mut i = 0;
    while i < bytes.len() {
        let rest = |k: usize| bytes.get(i + k).copied();
        if bytes[i] == '/' && rest(1) == Some('/') {
            while i < bytes.len() && bytes[i] != '\n' {
                i += 1;
            }
        } else if bytes[i] == '/' && rest(1) == Some('*') {
            i += 2;
            while i + 1 < bytes.len() && !(bytes[i] == '*' && bytes[i + 1] == '/') {
                i += 1;
            }
            i += 2;
        } else if bytes[i] == '"' {
            out.push('"');
            i += 1;
            while i < bytes.len() && bytes[i] != '"' {
                if bytes[i] == '\\' {
                    i += 1;
                }
                i += 1;
            }
            out.push('"');
            i += 1;
        } else if bytes[i] == '\'' && rest(2) == Some('\'') {
            // A char literal such as '{' must not count as a brace.
            i += 3;
        } else {
            out.push(bytes[i]);
            i += 1;
        }
    }
    strip_test_items(&out)
}

/// Removes every item that follows `#[cfg(test)]`: up to its `;` or through
/// its braces.
fn strip_test_items(code: &str) -> String {
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(at) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..at]);
        let item = &rest[at..];
        let semi = item.find(';').unwrap_or(item.len());
        let brace = item.find('{').unwrap_or(item.len());
        if semi < brace {
            rest = &item[(semi + 1).min(item.len())..];
            continue;
        }
        let mut depth = 0usize;
        let mut end = item.len();
        for (k, c) in item.char_indices().skip(brace) {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = k + 1;
                        break;
                    }
                }
                _ => {}
            }
        }
        rest = &item[end..];
    }
    out.push_str(rest);
    out
}

/// Expands a use tree (`a::b::{c, d::{e}, f as g}`) into its paths.
fn expand_use(tree: &str) -> Vec<Vec<String>> {
    // Aliases (`x as y`) name the same item: drop them, then the whitespace.
    let mut plain = tree.split_whitespace().collect::<Vec<_>>().join(" ");
    while let Some(at) = plain.find(" as ") {
        let end = plain[at + 4..].find([',', '}']).map_or(plain.len(), |k| at + 4 + k);
        plain.replace_range(at..end, "");
    }
    let tree: String = plain.chars().filter(|c| !c.is_whitespace()).collect();
    fn expand(prefix: &[String], tree: &str, out: &mut Vec<Vec<String>>) {
        if let Some(open) = tree.find('{') {
            let head: Vec<String> =
                tree[..open].split("::").filter(|s| !s.is_empty()).map(str::to_string).collect();
            let mut base = prefix.to_vec();
            base.extend(head);
            let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
            let mut depth = 0;
            let mut start = 0;
            for (k, c) in inner.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        expand(&base, &inner[start..k], out);
                        start = k + 1;
                    }
                    _ => {}
                }
            }
            expand(&base, &inner[start..], out);
        } else if !tree.is_empty() {
            let mut full = prefix.to_vec();
            full.extend(tree.split("::").filter(|s| !s.is_empty()).map(str::to_string));
            out.push(full);
        }
    }
    let mut out = Vec::new();
    expand(&[], &tree, &mut out);
    out
}

/// `use` statements (their trees) and whether each is `pub use`.
fn use_trees(code: &str) -> Vec<(bool, String)> {
    let mut out = Vec::new();
    let words: Vec<(usize, &str)> = code.match_indices("use ").collect();
    for (at, _) in words {
        let before = code[..at].chars().last();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let public = code[..at].trim_end().ends_with("pub") || code[..at].trim_end().ends_with(')');
        let end = code[at..].find(';').map_or(code.len(), |k| at + k);
        out.push((public, code[at + 4..end].to_string()));
    }
    out
}

/// Inline `crate::…` and `super::…` paths in code (outside `use`).
fn inline_paths(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for root in ["crate::", "super::"] {
        for (at, _) in code.match_indices(root) {
            let before = code[..at].chars().last();
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let path: String =
                code[at..].chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':').collect();
            out.push(path.split("::").filter(|s| !s.is_empty()).map(str::to_string).collect());
        }
    }
    out
}

struct Crate {
    modules: BTreeSet<Module>,
    /// Per module: item name → the module path it re-exports it from (unresolved).
    reexports: BTreeMap<Module, BTreeMap<String, Vec<String>>>,
    code: BTreeMap<Module, String>,
}

impl Crate {
    fn new(files: &BTreeMap<String, String>) -> Crate {
        let mut modules = BTreeSet::new();
        let mut code = BTreeMap::new();
        for (path, source) in files {
            let module = module_of(path);
            modules.insert(module.clone());
            code.insert(module, code_only(source));
        }
        let mut krate = Crate { modules, reexports: BTreeMap::new(), code };
        let mut reexports = BTreeMap::new();
        for (module, text) in &krate.code {
            let mut items = BTreeMap::new();
            for (public, tree) in use_trees(text) {
                if !public {
                    continue;
                }
                for path in expand_use(&tree) {
                    if let Some(name) = path.last() {
                        items.insert(name.clone(), path.clone());
                    }
                }
            }
            reexports.insert(module.clone(), items);
        }
        krate.reexports = reexports;
        krate
    }

    /// Absolute segments of `path` written in `module`, or `None` for an
    /// external crate.
    fn absolute(&self, module: &Module, path: &[String]) -> Option<Vec<String>> {
        let mut base: Vec<String> = match path.first().map(String::as_str) {
            Some("crate") => Vec::new(),
            Some("self") => module.clone(),
            Some("super") => {
                let mut b = module.clone();
                let mut k = 0;
                while path.get(k).map(String::as_str) == Some("super") {
                    b.pop();
                    k += 1;
                }
                b.extend(path[k..].iter().cloned());
                return Some(b);
            }
            Some(first) => {
                let mut child = module.clone();
                child.push(first.to_string());
                if !self.modules.contains(&child) {
                    return None;
                }
                module.clone()
            }
            None => return None,
        };
        let skip = usize::from(matches!(path.first().map(String::as_str), Some("crate") | Some("self")));
        base.extend(path[skip..].iter().cloned());
        Some(base)
    }

    /// The module that defines what absolute `path` names, following re-exports.
    fn target(&self, path: &[String], depth: usize) -> Option<Module> {
        let mut module: Module = Vec::new();
        let mut k = 0;
        while k < path.len() {
            let mut next = module.clone();
            next.push(path[k].clone());
            if self.modules.contains(&next) {
                module = next;
                k += 1;
            } else {
                break;
            }
        }
        if k < path.len() && depth < 8 {
            if let Some(from) = self.reexports.get(&module).and_then(|items| items.get(&path[k])) {
                if let Some(abs) = self.absolute(&module, from) {
                    if abs != path {
                        return self.target(&abs, depth + 1);
                    }
                }
            }
        }
        Some(module)
    }

    fn edges(&self) -> BTreeMap<Module, BTreeSet<Module>> {
        let mut graph: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
        for (module, text) in &self.code {
            let mut paths: Vec<Vec<String>> =
                use_trees(text).into_iter().flat_map(|(_, tree)| expand_use(&tree)).collect();
            paths.extend(inline_paths(text));
            let targets = graph.entry(module.clone()).or_default();
            for path in paths {
                let Some(abs) = self.absolute(module, &path) else { continue };
                let Some(target) = self.target(&abs, 0) else { continue };
                // A module naming itself or its own descendants is not a dependency.
                if target.starts_with(module) {
                    continue;
                }
                targets.insert(target);
            }
        }
        graph
    }
}

/// One cycle of `graph`, if any, as the modules along it.
fn find_cycle(graph: &BTreeMap<Module, BTreeSet<Module>>) -> Option<Vec<Module>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        New,
        Open,
        Done,
    }
    fn visit(
        node: &Module,
        graph: &BTreeMap<Module, BTreeSet<Module>>,
        marks: &mut BTreeMap<Module, Mark>,
        stack: &mut Vec<Module>,
    ) -> Option<Vec<Module>> {
        marks.insert(node.clone(), Mark::Open);
        stack.push(node.clone());
        for next in graph.get(node).into_iter().flatten() {
            match marks.get(next).copied().unwrap_or(Mark::New) {
                Mark::Open => {
                    let from = stack.iter().position(|m| m == next).unwrap_or(0);
                    let mut cycle = stack[from..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                Mark::New => {
                    if let Some(cycle) = visit(next, graph, marks, stack) {
                        return Some(cycle);
                    }
                }
                Mark::Done => {}
            }
        }
        stack.pop();
        marks.insert(node.clone(), Mark::Done);
        None
    }
    let mut marks = BTreeMap::new();
    for node in graph.keys() {
        if marks.get(node).copied().unwrap_or(Mark::New) == Mark::New {
            if let Some(cycle) = visit(node, graph, &mut marks, &mut Vec::new()) {
                return Some(cycle);
            }
        }
    }
    None
}

fn name(module: &Module) -> String {
    if module.is_empty() { "crate".to_string() } else { module.join("::") }
}

fn read_sources(dir: &Path, root: &Path, out: &mut BTreeMap<String, String>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir).expect("src readable").flatten().collect();
    entries.sort_by_key(|e| e.path());
    for entry in entries {
        let path = entry.path();
        let file = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
        if path.is_dir() {
            if file != "tests" {
                read_sources(&path, root, out);
            }
        } else if file.ends_with(".rs") && file != "tests.rs" {
            let relative = path.strip_prefix(root).expect("under src").to_string_lossy().replace('\\', "/");
            out.insert(relative, std::fs::read_to_string(&path).expect("source readable"));
        }
    }
}

fn files(list: &[(&str, &str)]) -> BTreeMap<String, String> {
    list.iter().map(|(p, s)| (p.to_string(), s.to_string())).collect()
}

#[test]
fn the_core_has_no_module_cycle() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut sources = BTreeMap::new();
    read_sources(&src, &src, &mut sources);
    assert!(sources.len() > 20, "read only {} files of {}", sources.len(), src.display());
    let graph = Crate::new(&sources).edges();
    if let Some(cycle) = find_cycle(&graph) {
        let names: Vec<String> = cycle.iter().map(name).collect();
        panic!("module cycle in rust/core/src: {}", names.join(" → "));
    }
}

/// The frame stepper is the one place that drives both the collision passes
/// and the solver (docs/architecture.md): every other top-level module uses
/// at most one of them.
#[test]
fn only_the_stepper_uses_both_collide_and_solve() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut sources = BTreeMap::new();
    read_sources(&src, &src, &mut sources);
    let graph = Crate::new(&sources).edges();
    let mut uses: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (from, targets) in &graph {
        let Some(top) = from.first() else { continue };
        for target in targets {
            if let Some(other) = target.first().filter(|t| *t != top) {
                uses.entry(top.clone()).or_default().insert(other.clone());
            }
        }
    }
    let both: Vec<&String> =
        uses.iter().filter(|(_, u)| u.contains("collide") && u.contains("solve")).map(|(m, _)| m).collect();
    assert_eq!(both, ["sequence"], "top-level modules using both collide and solve");
}

#[test]
fn the_check_sees_a_cycle_through_a_reexport_and_an_inline_path() {
    let sources = files(&[
        ("lib.rs", "pub mod a;"),
        ("a/mod.rs", "mod x;\nmod y;\npub use x::Thing;"),
        ("a/x.rs", "use super::y::Other;\npub struct Thing;"),
        ("a/y.rs", "pub struct Other;\nfn f() -> crate::a::Thing { todo!() }"),
    ]);
    let cycle = find_cycle(&Crate::new(&sources).edges()).expect("x → y → x");
    assert_eq!(cycle.iter().map(name).collect::<Vec<_>>(), ["a::x", "a::y", "a::x"]);
}

#[test]
fn a_parent_listing_its_children_and_test_code_are_not_edges() {
    let sources = files(&[
        ("lib.rs", "pub mod a;\npub mod b;"),
        ("a/mod.rs", "mod x;\npub use x::Thing;\npub fn g() { x::h() }"),
        ("a/x.rs", "use super::g; // crate::b::B\npub struct Thing;\n#[cfg(test)]\nmod tests { use crate::b::B; }"),
        ("b.rs", "use crate::a::Thing;\npub struct B;"),
    ]);
    let graph = Crate::new(&sources).edges();
    assert_eq!(find_cycle(&graph), None);
    let x: Module = vec!["a".into(), "x".into()];
    assert_eq!(graph[&x], BTreeSet::from([vec!["a".to_string()]]));
    assert_eq!(graph[&vec!["b".to_string()]], BTreeSet::from([x]));
}
