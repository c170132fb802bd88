//! The crates' layering, as the README's Layout table states it: each library depends only on
//! the emccd crates listed here (its `[dependencies]` and `[dev-dependencies]`), so a back-edge —
//! a lower layer reaching up — fails this test instead of growing unnoticed.

use std::collections::BTreeSet;

/// crate folder → the emccd crates it may use.
const ALLOWED: [(&str, &[&str]); 6] = [
    ("io", &[]),
    ("profile", &["emccd-io"]),
    ("camera", &["emccd-calib", "emccd-io", "emccd-profile"]),
    ("eval", &["emccd-camera", "emccd-io", "emccd-profile"]),
    ("calib", &["emccd-io", "emccd-profile"]),
    (
        "nn",
        &["emccd-camera", "emccd-eval", "emccd-io", "emccd-profile"],
    ),
];

fn emccd_deps(krate: &str) -> BTreeSet<String> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("crates")
        .join(krate)
        .join("Cargo.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let doc: toml::Table = text.parse().unwrap();
    ["dependencies", "dev-dependencies"]
        .iter()
        .filter_map(|k| doc.get(*k).and_then(|t| t.as_table()))
        .flat_map(|t| t.keys().cloned())
        .filter(|k| k.starts_with("emccd-"))
        .collect()
}

#[test]
fn libraries_depend_only_downward() {
    let dirs: BTreeSet<String> = std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/crates"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "cli")
        .collect();
    let listed: BTreeSet<String> = ALLOWED.iter().map(|(k, _)| k.to_string()).collect();
    assert_eq!(dirs, listed, "a library crate is missing from the layering");
    for (krate, allowed) in ALLOWED {
        let allowed: BTreeSet<String> = allowed.iter().map(|s| s.to_string()).collect();
        let deps = emccd_deps(krate);
        let extra: Vec<&String> = deps.difference(&allowed).collect();
        assert!(
            extra.is_empty(),
            "emccd-{krate} depends on {extra:?}, outside its layer (README, Layout)"
        );
    }
}
