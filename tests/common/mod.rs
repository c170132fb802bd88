//! Helpers shared by the end-to-end tests: run the built binary, require success, find data.
#![allow(dead_code)] // each test binary uses its own subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `emccd ARGS` in `cwd`.
pub fn emccd(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_emccd"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run emccd")
}

/// Requires success; returns stdout.
pub fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "exit {:?}\nstdout: {}\nstderr: {}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A path under the repository root.
pub fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// A path under `tests/data` (the real files the tests read, with their licences).
pub fn data(rel: &str) -> PathBuf {
    repo("tests/data").join(rel)
}

/// Sets the modification time of `path` and everything in it two hours back: what a killed
/// run left an hour ago or more.
pub fn age(path: &Path) {
    let then = std::time::SystemTime::now() - std::time::Duration::from_secs(7200);
    if path.is_dir() {
        for e in std::fs::read_dir(path).unwrap() {
            age(&e.unwrap().path());
        }
    }
    std::fs::File::open(path)
        .unwrap()
        .set_modified(then)
        .unwrap();
}
