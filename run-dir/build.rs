//! Names the git revision the program is built from (`JSAE_GIT_COMMIT`, summary.json's
//! `git_commit`): "unknown" outside a git checkout (a Docker build context, a tarball).

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
        .filter(|s| !s.is_empty())
}

fn main() {
    let commit = git(&["rev-parse", "HEAD"]).unwrap_or_else(|| "unknown".into());
    println!("cargo::rustc-env=JSAE_GIT_COMMIT={commit}");
    // a new commit or another branch: built again with its name (HEAD is the worktree's, the
    // branches are the repository's; only paths that exist: cargo counts a missing one as
    // changed, every build)
    let worktree = git(&["rev-parse", "--absolute-git-dir"]);
    let common = git(&["rev-parse", "--path-format=absolute", "--git-common-dir"]);
    let watched = [
        (&worktree, "HEAD"),
        (&common, "refs/heads"),
        (&common, "packed-refs"),
    ];
    for (dir, moved) in watched {
        let Some(dir) = dir else { continue };
        let path = std::path::Path::new(dir).join(moved);
        if path.exists() {
            println!("cargo::rerun-if-changed={}", path.display());
        }
    }
}
