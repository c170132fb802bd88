//! The crates' layering is what the README's Layout section states: its "Layering" paragraph
//! names, for each library, the emccd crates it uses, and each library's `[dependencies]` and
//! `[dev-dependencies]` must be exactly those. A back-edge (a lower layer reaching up) or a
//! README that no longer says what the manifests do fails this test.

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
const LAYERS: [&[&str]; 5] = [
    &["io"],
    &["profile"],
    &["camera", "calib"],
    &["eval"],
    &["nn"],
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
