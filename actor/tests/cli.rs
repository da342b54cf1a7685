//! The `jsae` command line: help, bad flags and bad settings exit 2 with a one-line reason.

use std::process::Command;

fn jsae(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(args)
        .output()
        .expect("jsae runs")
}

#[test]
fn help_answers_and_bad_input_exits_2_with_a_reason() {
    let help = jsae(&["train", "--help"]);
    assert!(help.status.success());
    assert!(String::from_utf8_lossy(&help.stdout).contains("--env-steps"));

    let bad_flag = jsae(&["train", "--env", "nowhere"]);
    assert_eq!(bad_flag.status.code(), Some(2));

    let bad_value = jsae(&["train", "--env-steps", "100", "--quiet"]);
    assert_eq!(bad_value.status.code(), Some(2));
    let reason = String::from_utf8_lossy(&bad_value.stderr);
    assert_eq!(reason.trim().lines().count(), 1, "{reason}");
    assert!(reason.contains("pretrain_transitions"), "{reason}");

    let missing = jsae(&["train", "--config", "/nonexistent/run.toml"]);
    assert_eq!(missing.status.code(), Some(2));
}

#[test]
fn a_short_run_prints_its_summary() {
    let dir = std::env::temp_dir().join(format!("jsae-cli-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cfg = dir.with_extension("toml");
    std::fs::write(
        &cfg,
        "envs_per_actor = 4\nrollout_len = 32\neval_episodes = 2\n[embedding]\npretrain_transitions = 1000\npretrain_epochs = 2\n[ppo]\nepochs = 1\n",
    )
    .expect("config");
    let out = jsae(&[
        "train",
        "--env",
        "slotmachine",
        "--algo",
        "jsae",
        "--seed",
        "5",
        "--env-steps",
        "3000",
        "--quiet",
        "--out",
        dir.to_str().unwrap_or("."),
        "--config",
        cfg.to_str().unwrap_or("."),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("\"eval_return_mean\"") && stdout.contains("\"seed\": 5"),
        "{stdout}"
    );
    assert!(dir.join("summary.json").exists() && dir.join("learning_curve.svg").exists());
    // separate processes by default: each left its log
    for name in ["embedder", "learner", "actor-0"] {
        let log = dir.join("logs").join(format!("{name}.log"));
        assert!(log.exists(), "{}", log.display());
    }
    let learner_log = std::fs::read_to_string(dir.join("logs/learner.log")).unwrap_or_default();
    assert!(
        learner_log.contains("listening on 127.0.0.1:"),
        "{learner_log}"
    );
}

#[test]
fn the_services_answer_help_and_refuse_bad_input_with_exit_2() {
    for service in ["embedder", "learner", "actor"] {
        let help = jsae(&[service, "--help"]);
        assert!(help.status.success(), "{service}");
        assert!(String::from_utf8_lossy(&help.stdout).contains("--env"));
        let bad = jsae(&[service, "--env", "nowhere"]);
        assert_eq!(bad.status.code(), Some(2), "{service}");
    }
    let actor = Command::new(env!("CARGO_BIN_EXE_jsae-actor"))
        .args([
            "--learner",
            "http://127.0.0.1:9",
            "--env",
            "gridworld",
            "--seed",
            "1",
        ])
        .output()
        .expect("jsae-actor runs");
    assert_eq!(actor.status.code(), Some(2), "jsae needs --embedder");
    let reason = String::from_utf8_lossy(&actor.stderr);
    assert!(reason.contains("--embedder"), "{reason}");
}
