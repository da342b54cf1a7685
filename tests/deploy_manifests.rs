//! deploy/k8s validated offline: every manifest against the Kubernetes schemas
//! (kubernetes-validate, strict: unknown fields refused) for the oldest and the newest
//! version it knows, then the structural rules (scripts/python/k8s_check.py): resources on
//! every container, native gRPC readiness and liveness probes on every served port, Services
//! that select pods, a kustomization listing every file. A broken copy must be refused.

use std::path::Path;
use std::process::Command;

use jsae_tests::{repo_root, venv_python};

fn manifests(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .expect("deploy/k8s")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.extension().is_some_and(|e| e == "yaml")
                && p.file_name().is_some_and(|n| n != "kustomization.yaml")
        })
        .collect();
    files.sort();
    files
}

fn validate(python: &Path, version: &str, files: &[std::path::PathBuf]) -> std::process::Output {
    Command::new(python)
        .args(["-m", "kubernetes_validate", "--strict", "-k", version])
        .args(files)
        .output()
        .expect("kubernetes-validate runs")
}

#[test]
fn the_kubernetes_manifests_pass_offline_validation() {
    let python = venv_python();
    let dir = repo_root().join("deploy/k8s");
    let files = manifests(&dir);
    assert!(files.len() >= 6, "{files:?}");
    for version in ["1.30.0", "1.37.0"] {
        let out = validate(&python, version, &files);
        let text = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "Kubernetes {version}: {text}");
        assert_eq!(text.matches("passed for resource").count(), 15, "{text}");
    }
    let out = Command::new(&python)
        .arg(repo_root().join("scripts/python/k8s_check.py"))
        .arg(&dir)
        .output()
        .expect("k8s_check.py runs");
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );

    // the validator is not a rubber stamp: a misspelt field and a wrong type are refused
    let bad = std::env::temp_dir().join(format!("jsae-k8s-bad-{}", std::process::id()));
    std::fs::create_dir_all(&bad).expect("temp dir");
    let actor = std::fs::read_to_string(dir.join("actor.yaml")).expect("actor.yaml");
    for (name, text) in [
        ("typo.yaml", actor.replace("replicas: 3", "replica: 2")),
        ("type.yaml", actor.replace("replicas: 3", "replicas: two")),
    ] {
        let path = bad.join(name);
        std::fs::write(&path, text).expect("write");
        let out = validate(&python, "1.30.0", std::slice::from_ref(&path));
        assert!(!out.status.success(), "{name} passed");
    }
    let _ = std::fs::remove_dir_all(&bad);
}
