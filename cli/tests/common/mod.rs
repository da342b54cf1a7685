//! Helpers shared by the cli crate's integration tests.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the cli crate lives in the workspace")
        .to_path_buf()
}

/// The test venv's python (scripts/setup-python.sh creates it on first use).
pub fn venv_python() -> PathBuf {
    let out = Command::new(repo_root().join("scripts/setup-python.sh"))
        .output()
        .expect("scripts/setup-python.sh runs");
    assert!(
        out.status.success(),
        "scripts/setup-python.sh failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}
