//! `jsae config` prints a pair's settings as a commented settings file that reads back to the
//! same settings, `--set KEY=VALUE` overrides any key like a settings file would, and each
//! command's help lists its own flags with their true defaults.

use std::process::Command;

fn jsae(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(args)
        .output()
        .expect("jsae runs")
}

fn stdout(out: &std::process::Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn config_prints_every_key_with_its_doc_and_reads_back_the_same() {
    let text = stdout(&jsae(&["config", "--env", "half-cheetah", "--algo", "ppo"]));
    assert!(text.contains("env = \"half-cheetah\""), "{text}");
    assert!(text.contains("[ppo]"), "{text}");
    // the learning rate's line follows its doc comment
    let lines: Vec<&str> = text.lines().collect();
    let lr = lines
        .iter()
        .position(|l| l.starts_with("lr = "))
        .expect("ppo.lr listed");
    assert!(lines[lr - 1].starts_with('#'), "{text}");

    let file = std::env::temp_dir().join(format!("jsae-config-{}.toml", std::process::id()));
    std::fs::write(&file, &text).expect("written");
    let again = stdout(&jsae(&[
        "config",
        "--config",
        file.to_str().unwrap_or_default(),
    ]));
    let _ = std::fs::remove_file(&file);
    assert_eq!(again, text);
}

#[test]
fn set_overrides_any_key_and_is_refused_like_a_file() {
    let text = stdout(&jsae(&[
        "config",
        "--env",
        "gridworld-discrete",
        "--set",
        "ppo.lr=0.0007",
        "--set",
        "environment.gridworld.max_steps=77",
    ]));
    assert!(text.lines().any(|l| l == "lr = 0.0007"), "{text}");
    assert!(text.lines().any(|l| l == "max_steps = 77"), "{text}");

    for bad in ["ppo.learning_rate=1", "ppo.lr=fast", "ppo.lr"] {
        let out = jsae(&["config", "--set", bad]);
        assert_eq!(out.status.code(), Some(2), "--set {bad}");
        let reason = String::from_utf8_lossy(&out.stderr);
        assert_eq!(reason.trim().lines().count(), 1, "{reason}");
    }
}

#[test]
fn each_command_lists_its_own_flags_with_true_defaults() {
    let help = |args: &[&str]| stdout(&jsae(args));
    for client in [
        &["recommend", "--help"][..],
        &["health", "--help"],
        &["submit-sessions", "--help"],
    ] {
        let text = help(client);
        assert!(text.contains("--tls-ca"), "{text}");
        assert!(
            !text.contains("--tls-client-ca"),
            "a server's flag in {client:?}:\n{text}"
        );
    }
    let baseline = help(&["recommender-baseline", "--help"]);
    assert!(baseline.contains("[default: recommender"), "{baseline}");
    assert!(!baseline.contains("gridworld-discrete]"), "{baseline}");
    for service in ["embedder", "learner", "actor"] {
        let text = help(&[service, "--help"]);
        assert!(
            text.contains("needed unless --config"),
            "{service}:\n{text}"
        );
        assert!(!text.contains("else 1]"), "{service}:\n{text}");
    }
    let plot = help(&["plot", "--help"]);
    assert!(plot.contains("--run <DIR>"), "{plot}");
    assert!(help(&["train", "--help"]).contains("--set <KEY=VALUE>"));
}

/// The configuration page's example is `jsae config`'s output (`JSAE_WRITE_DOCS=1` writes
/// it anew).
#[test]
fn the_configuration_page_shows_what_jsae_config_prints() {
    let text = stdout(&jsae(&[
        "config",
        "--env",
        "gridworld-discrete",
        "--algo",
        "jsae",
    ]));
    let page = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../docs/src/configuration/gridworld-discrete-jsae.toml");
    if std::env::var_os("JSAE_WRITE_DOCS").is_some() {
        std::fs::write(&page, &text).expect("written");
    }
    let committed = std::fs::read_to_string(&page).unwrap_or_default();
    assert!(
        committed == text,
        "{} is not what `jsae config --env gridworld-discrete --algo jsae` prints: run this test \
         with JSAE_WRITE_DOCS=1",
        page.display()
    );
}
