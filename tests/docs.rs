//! The book in `docs/` and the README: every path, command, link and include they name exists
//! and the crate map matches the manifests (`scripts/check-docs.py`), and the book builds with
//! the pinned mdbook (`scripts/install-mdbook.sh`; `.ci/run` installs it, elsewhere the build
//! is checked where it is installed).

use std::process::Command;

use jsae_tests::repo_root as root;

#[test]
fn every_path_command_and_link_the_docs_name_exists() {
    let out = Command::new("python3")
        .arg("scripts/check-docs.py")
        .current_dir(root())
        .output()
        .expect("python3 runs");
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scripts/check-docs.py:\n{text}");
}

#[test]
fn the_book_builds_with_mdbook() {
    let mdbook = root().join("target/tools/bin/mdbook");
    if !mdbook.exists() {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI runs scripts/install-mdbook.sh first; {} is missing",
            mdbook.display()
        );
        eprintln!("mdbook is not installed (scripts/install-mdbook.sh): the build is not checked");
        return;
    }
    let dest = std::env::temp_dir().join(format!("jsae-book-{}", std::process::id()));
    let out = Command::new(&mdbook)
        .args(["build", "docs", "--dest-dir"])
        .arg(&dest)
        .current_dir(root())
        .output()
        .expect("mdbook runs");
    let _ = std::fs::remove_dir_all(&dest);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "mdbook build docs:\n{text}");
    let warnings: Vec<&str> = text
        .lines()
        .filter(|l| l.contains("WARN") || l.contains("ERROR"))
        .collect();
    assert!(
        warnings.is_empty(),
        "mdbook build docs warned:\n{}",
        warnings.join("\n")
    );
}
