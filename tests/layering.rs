//! The crates' layering is what the README's Layout section states: its "Layering" paragraph
//! names, for each library, the emccd crates it uses, and each library's `[dependencies]` and
//! `[dev-dependencies]` must be exactly those. A back-edge (a lower layer reaching up) or a
//! README that no longer says what the manifests do fails this test. Inside every crate, the
//! top-level modules must use each other without a cycle (read from their `crate::` paths,
//! with the items the crate's root re-exports counted as their modules'). The documentation's
//! checks (`docs.rs`) run here too: one test binary for the repository's structure.

mod docs;

use std::collections::{BTreeMap, BTreeSet};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The emccd crates a library's manifest names: in `[dependencies]`, `[dev-dependencies]` and
/// `[build-dependencies]`, also under `[target.'cfg(…)'.…]`, by the package a renamed entry
/// (`x = { package = "emccd-…" }`) points at.
fn emccd_deps(krate: &str) -> BTreeSet<String> {
    let path = std::path::Path::new(ROOT)
        .join("crates")
        .join(krate)
        .join("Cargo.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let doc: toml::Table = text.parse().unwrap();
    fn tables_of(t: &toml::Table) -> Vec<&toml::Table> {
        ["dependencies", "dev-dependencies", "build-dependencies"]
            .iter()
            .filter_map(|k| t.get(*k).and_then(|v| v.as_table()))
            .collect()
    }
    let mut tables = tables_of(&doc);
    for target in doc
        .get("target")
        .and_then(|t| t.as_table())
        .into_iter()
        .flat_map(|t| t.values())
        .filter_map(|v| v.as_table())
    {
        tables.extend(tables_of(target));
    }
    tables
        .into_iter()
        .flat_map(|t| t.iter())
        .map(|(key, v)| {
            v.get("package")
                .and_then(|p| p.as_str())
                .unwrap_or(key)
                .to_string()
        })
        .filter(|k| k.starts_with("emccd-"))
        .map(|k| k.trim_start_matches("emccd-").to_string())
        .collect()
}

/// The README's layering: crate folder → the crate folders it uses, read from the paragraph
/// "Layering (…): `emccd-io` uses no emccd crate; `emccd-profile` → io; …; the `emccd` binary …".
fn readme_layering() -> BTreeMap<String, BTreeSet<String>> {
    let readme = std::fs::read_to_string(format!("{ROOT}/README.md")).unwrap();
    let start = readme
        .find("Layering (")
        .expect("README: the Layering paragraph");
    let para: String = readme[start..]
        .split("\n\n")
        .next()
        .unwrap()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ");
    let body = &para[para.find("):").expect("Layering (…):") + 2..];
    let mut layers = BTreeMap::new();
    for part in body.split(';').map(str::trim) {
        if part.starts_with("the `emccd` binary") {
            break;
        }
        let name = part
            .strip_prefix("`emccd-")
            .and_then(|r| r.split_once('`'))
            .map(|(n, _)| n.to_string())
            .unwrap_or_else(|| panic!("README layering: {part:?} does not start with a crate"));
        let uses: BTreeSet<String> = match part.split_once('→') {
            Some((_, list)) => list
                .split(',')
                .map(|s| s.trim().trim_end_matches('.').to_string())
                .collect(),
            None if part.ends_with("uses no emccd crate") => BTreeSet::new(),
            None => panic!("README layering: {part:?} has no → list"),
        };
        layers.insert(name, uses);
    }
    layers
}

/// The library crates: every folder under `crates/` but the binary's.
fn libraries() -> BTreeSet<String> {
    std::fs::read_dir(format!("{ROOT}/crates"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "cli")
        .collect()
}

#[test]
fn libraries_depend_on_what_the_readme_says() {
    let dirs = libraries();
    let layers = readme_layering();
    let listed: BTreeSet<String> = layers.keys().cloned().collect();
    assert_eq!(
        dirs, listed,
        "the README's layering lists every library crate"
    );
    for (krate, uses) in &layers {
        assert_eq!(
            &emccd_deps(krate),
            uses,
            "emccd-{krate}: its Cargo.toml and the README's Layering paragraph differ"
        );
    }
}

/// The layers, lowest first: a crate may use only crates of a lower layer, so an upward or
/// sideways edge fails here even if the README were edited to match it. The binary and the
/// Python package sit above every library (a library naming `emccd-python` has no layer and
/// fails too).
const LAYERS: [&[&str]; 7] = [
    &["io"],
    &["profile"],
    &["camera", "calib"],
    &["eval"],
    &["classical"],
    &["nn", "count"],
    &["train", "denoise"],
];

fn layer_of(krate: &str) -> usize {
    LAYERS
        .iter()
        .position(|l| l.contains(&krate))
        .unwrap_or_else(|| panic!("emccd-{krate} has no layer in tests/layering.rs's LAYERS"))
}

#[test]
fn every_edge_points_down_the_layers() {
    let libraries = libraries();
    for krate in &libraries {
        let own = layer_of(krate);
        for dep in emccd_deps(krate) {
            assert!(
                layer_of(&dep) < own,
                "emccd-{krate} (layer {own}) uses emccd-{dep} (layer {}): edges point down",
                layer_of(&dep)
            );
        }
    }
}

/// A crate's root file (`src/lib.rs`, or the binary's `main.rs`) and the folder its modules
/// live in.
fn crate_root(krate: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = std::path::Path::new(ROOT).join("crates").join(krate);
    let lib = dir.join("src/lib.rs");
    if lib.is_file() {
        (lib, dir.join("src"))
    } else {
        (dir.join("main.rs"), dir)
    }
}

/// Every `.rs` file under `path` (a module's file, or its folder).
fn rust_files(path: &std::path::Path) -> Vec<std::path::PathBuf> {
    if path.is_file() {
        return vec![path.to_path_buf()];
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(path).unwrap() {
        out.extend(rust_files(&e.unwrap().path()));
    }
    out
}

/// The first path segments after `crate::` in Rust source, comments left out: `crate::a::b`
/// gives `a`, `use crate::{a::X, b}` gives `a` and `b`.
fn crate_paths(src: &str) -> BTreeSet<String> {
    let code: String = src
        .lines()
        .map(|l| l.split("//").next().unwrap())
        .collect::<Vec<_>>()
        .join("\n");
    let ident = |s: &str| -> String {
        s.trim()
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect()
    };
    let mut out = BTreeSet::new();
    let mut rest = code.as_str();
    while let Some(i) = rest.find("crate::") {
        let after = &rest[i + "crate::".len()..];
        if let Some(group) = after.strip_prefix('{') {
            // The group's top-level items, up to its matching brace: `a::{X, Y}, b` names `a`, `b`.
            let mut depth = 0;
            let mut item = String::new();
            for c in group.chars() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        out.insert(ident(&item));
                        item.clear();
                        continue;
                    }
                    _ => {}
                }
                if depth == 0 {
                    item.push(c);
                }
            }
            out.insert(ident(&item));
        } else {
            out.insert(ident(after));
        }
        rest = after;
    }
    out.remove("");
    out
}

/// A crate's module graph: top-level module → the top-level modules it names through `crate::`
/// (an item the root re-exports counts as its module; the root itself is no module).
fn module_graph(krate: &str) -> BTreeMap<String, BTreeSet<String>> {
    let (root, dir) = crate_root(krate);
    let mut modules = BTreeMap::new();
    for e in std::fs::read_dir(&dir).unwrap() {
        let path = e.unwrap().path();
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let is_module = (path.is_dir() && path.join("mod.rs").is_file())
            || (path.extension().is_some_and(|x| x == "rs") && path != root);
        if is_module {
            modules.insert(name, path);
        }
    }
    // `pub use module::{A, B};` in the root (on one line or several): A and B belong to
    // `module`.
    let root_src: String = std::fs::read_to_string(&root)
        .unwrap()
        .lines()
        .map(|l| l.split("//").next().unwrap())
        .collect::<Vec<_>>()
        .join(" ");
    let mut owner: BTreeMap<String, String> = BTreeMap::new();
    for statement in root_src.split(';') {
        // The statement may follow an item's closing brace or an attribute on its line.
        let Some(body) = ["pub use ", "pub(crate) use "]
            .iter()
            .find_map(|p| statement.rfind(p).map(|i| &statement[i + p.len()..]))
        else {
            continue;
        };
        let Some((module, items)) = body.split_once("::") else {
            continue;
        };
        if !modules.contains_key(module.trim()) {
            continue;
        }
        for item in items
            .trim()
            .trim_matches(|c| c == '{' || c == '}')
            .split(',')
        {
            let item = item.trim().rsplit("::").next().unwrap().trim().to_string();
            owner.insert(item, module.trim().to_string());
        }
    }
    modules
        .iter()
        .map(|(name, path)| {
            let uses = rust_files(path)
                .iter()
                .flat_map(|f| crate_paths(&std::fs::read_to_string(f).unwrap()))
                .filter_map(|seg| {
                    if modules.contains_key(&seg) {
                        Some(seg)
                    } else {
                        owner.get(&seg).cloned()
                    }
                })
                .filter(|m| m != name)
                .collect();
            (name.clone(), uses)
        })
        .collect()
}

/// A cycle in `graph`, if there is one, as the modules along it.
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|n| n == node) {
            let mut cycle = path[i..].to_vec();
            cycle.push(node.to_string());
            return Some(cycle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(c) = visit(next, graph, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|n| visit(n, graph, &mut Vec::new(), &mut done))
}

/// Inside every crate (the binary's too), modules use each other without a cycle: a module that
/// reaches back to one that uses it fails here, naming the loop.
#[test]
fn no_crate_has_a_module_cycle() {
    let mut crates = libraries();
    crates.insert("cli".into());
    for krate in &crates {
        let graph = module_graph(krate);
        assert!(
            graph.len() > 1 || krate == "cli",
            "emccd-{krate}: no modules found"
        );
        if let Some(cycle) = find_cycle(&graph) {
            panic!("emccd-{krate}: modules in a cycle: {}", cycle.join(" → "));
        }
    }
}

#[test]
fn the_cycle_finder_finds_cycles() {
    let g = |edges: &[(&str, &str)]| {
        let mut m: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for (a, b) in edges {
            m.entry(a.to_string()).or_default().insert(b.to_string());
            m.entry(b.to_string()).or_default();
        }
        m
    };
    assert!(find_cycle(&g(&[("a", "b"), ("b", "c"), ("a", "c")])).is_none());
    let c = find_cycle(&g(&[("a", "b"), ("b", "c"), ("c", "a")])).unwrap();
    assert_eq!(c.len(), 4, "{c:?}");
    assert_eq!(
        crate_paths("use crate::{a::{X, Y}, b};\n// crate::c\nlet x = crate::d::f();"),
        ["a", "b", "d"].iter().map(|s| s.to_string()).collect()
    );
}
