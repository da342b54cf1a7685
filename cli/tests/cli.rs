//! The `jsae` command line: help, bad flags and bad settings exit 2 with a one-line reason.

mod common;

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

    // a bad value in the file: one line with the dotted key and its line (rough edge 9)
    let file = std::env::temp_dir().join(format!("jsae-cli-bad-{}.toml", std::process::id()));
    std::fs::write(&file, "seed = 3\n[ppo]\nepochs = 2\nlr = \"x\"\n").expect("file");
    let bad_file = jsae(&["train", "--config", file.to_str().unwrap_or_default()]);
    assert_eq!(bad_file.status.code(), Some(2));
    let reason = String::from_utf8_lossy(&bad_file.stderr);
    assert_eq!(reason.trim().lines().count(), 1, "{reason}");
    assert!(reason.contains("ppo.lr (line 4): invalid type"), "{reason}");
    let _ = std::fs::remove_file(&file);

    // one batch larger than the whole budget is refused, not run silently (rough edge 3)
    let batch = jsae(&[
        "train",
        "--algo",
        "ppo",
        "--envs",
        "512",
        "--env-steps",
        "10000",
    ]);
    assert_eq!(batch.status.code(), Some(2));
    let reason = String::from_utf8_lossy(&batch.stderr);
    assert!(reason.contains("less than one batch"), "{reason}");
}

#[test]
fn a_short_run_prints_its_summary() {
    let dir = std::env::temp_dir().join(format!("jsae-cli-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cfg = dir.with_extension("toml");
    std::fs::write(
        &cfg,
        "envs_per_actor = 4\nrollout_len = 32\neval_episodes = 2\n[embedding]\npretrain_transitions = 1000\npretrain_per_action = 0\npretrain_epochs = 2\n[ppo]\nepochs = 1\n",
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
    // no colour codes in a file (rough edge 4)
    assert!(!learner_log.contains('\u{1b}'), "{learner_log}");

    // what started the run, and when, and from which revision (rough edge 12)
    let started: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("summary.json")).unwrap_or_default(),
    )
    .expect("summary.json");
    let typed: Vec<&str> = started["command_line"]
        .as_array()
        .map(|a| a.iter().filter_map(|v| v.as_str()).collect())
        .unwrap_or_default();
    assert!(typed.windows(2).any(|w| w == ["--seed", "5"]), "{typed:?}");
    assert_eq!(typed.get(1), Some(&"train"), "{typed:?}");
    assert!(started["started_unix_s"].as_u64().unwrap_or(0) > 1_700_000_000);
    assert!(!started["git_commit"].as_str().unwrap_or("").is_empty());

    // the learner process wrote the metrics for TensorBoard too
    common::assert_tensorboard_holds_the_metrics(&dir);

    evaluates_again_from_its_checkpoints(&dir);
}

/// The finished run in `dir` evaluates again from its checkpoints: the run's own evaluation
/// seed reproduces summary.json's evaluation; the mode decode and other seeds are asked for;
/// a closed output ends it cleanly; a run that is not there exits 2.
fn evaluates_again_from_its_checkpoints(dir: &std::path::Path) {
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("summary.json")).unwrap_or_default(),
    )
    .expect("summary");
    let d = dir.to_str().unwrap_or(".");
    let eval = jsae(&["eval", "--run", d]);
    assert!(
        eval.status.success(),
        "{}",
        String::from_utf8_lossy(&eval.stderr)
    );
    let again: serde_json::Value = serde_json::from_slice(&eval.stdout).expect("json");
    for key in [
        "eval_episodes",
        "eval_return_mean",
        "eval_success_rate",
        "eval_stochastic_return_mean",
    ] {
        assert_eq!(again[key], summary[key], "{key}");
    }
    let mode = jsae(&[
        "eval",
        "--run",
        d,
        "--episodes",
        "3",
        "--seed",
        "9",
        "--decode",
        "mode",
    ]);
    assert!(
        mode.status.success(),
        "{}",
        String::from_utf8_lossy(&mode.stderr)
    );
    let mode: serde_json::Value = serde_json::from_slice(&mode.stdout).expect("json");
    assert_eq!(
        (mode["eval_episodes"].as_u64(), mode["decode"].as_str()),
        (Some(3), Some("mode"))
    );
    // its output closed under it (`jsae eval --run X | head -4`): a clean exit, no panic
    let mut closed = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["eval", "--run", d])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("starts");
    drop(closed.stdout.take());
    let done = closed.wait_with_output().expect("ends");
    let stderr = String::from_utf8_lossy(&done.stderr);
    assert!(done.status.success(), "{:?}: {stderr}", done.status);
    assert!(!stderr.contains("panicked"), "{stderr}");
    let missing = jsae(&["eval", "--run", "/nonexistent/run"]);
    assert_eq!(missing.status.code(), Some(2));
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
    let actor = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args([
            "actor",
            "--learner",
            "http://127.0.0.1:9",
            "--env",
            "gridworld",
            "--seed",
            "1",
        ])
        .output()
        .expect("jsae actor runs");
    assert_eq!(actor.status.code(), Some(2), "jsae needs --embedder");
    let reason = String::from_utf8_lossy(&actor.stderr);
    assert!(reason.contains("--embedder"), "{reason}");
}

#[test]
fn services_stop_with_exit_0_on_sigterm() {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let dir = std::env::temp_dir().join(format!("jsae-cli-term-{}", std::process::id()));
    let out = dir.to_str().unwrap_or(".").to_string();
    let common = ["--env", "gridworld", "--algo", "ppo", "--seed", "1"];
    let learner_args: Vec<&str> = [
        "learner",
        "--listen",
        "127.0.0.1:0",
        "--env-steps",
        "100000",
    ]
    .into_iter()
    .chain(common)
    .chain(["--out", &out])
    .collect();
    let embedder_args: Vec<&str> = ["embedder", "--listen", "127.0.0.1:0"]
        .into_iter()
        .chain(common)
        .collect();
    for args in [learner_args, embedder_args] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_jsae"))
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("reads");
        assert!(line.contains("listening on 127.0.0.1:"), "{line}");
        let pid = child.id().to_string();
        let sent = Command::new("kill").args(["-TERM", &pid]).status();
        assert!(sent.is_ok_and(|s| s.success()));
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
        let status = loop {
            if let Some(s) = child.try_wait().expect("waits") {
                break s;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "{args:?} ignored SIGTERM"
            );
            std::thread::sleep(std::time::Duration::from_millis(50));
        };
        assert_eq!(status.code(), Some(0), "{args:?}: {status}");
    }
}

#[test]
fn a_refused_connection_says_why() {
    for args in [
        &["health", "--addr", "127.0.0.1:1", "--timeout-ms", "2000"][..],
        &["recommend", "--addr", "127.0.0.1:1", "--k", "3", "24852"][..],
    ] {
        let out = jsae(args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let reason = String::from_utf8_lossy(&out.stderr).to_lowercase();
        // not only tonic's "transport error" (rough edge 7)
        assert!(reason.contains("refused"), "{args:?}: {reason}");
    }
}

#[test]
fn an_actor_refuses_a_bad_address_and_warns_when_refused() {
    // a malformed address: exit 2 at once, naming the flag (rough edge 6)
    let actor = |algo: &str, learner: &str, embedder: Option<&str>| {
        let mut args = vec!["actor", "--env", "gridworld-discrete", "--seed", "1"];
        args.extend(["--algo", algo, "--learner", learner]);
        args.extend(embedder.map(|e| ["--embedder", e]).into_iter().flatten());
        args.into_iter().map(String::from).collect::<Vec<_>>()
    };
    for (flag, args) in [
        (
            "--embedder",
            actor("jsae", "http://127.0.0.1:1", Some("not-a-url")),
        ),
        ("--learner", actor("ppo", "not-a-url", None)),
    ] {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = jsae(&args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let reason = String::from_utf8_lossy(&out.stderr);
        assert!(reason.contains(flag), "{reason}");
    }
    // a well-formed address nobody answers on: retried, and each refusal said at WARN
    let mut child = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(actor("ppo", "http://127.0.0.1:1", None))
        .env("RUST_LOG", "info")
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("actor starts");
    std::thread::sleep(std::time::Duration::from_secs(4));
    let _ = child.kill();
    let out = child.wait_with_output().expect("actor output");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(
        log.contains("WARN") && log.to_lowercase().contains("refused"),
        "{log}"
    );
}

/// The processes whose parent is `pid`.
fn children_of(pid: u32) -> Vec<u32> {
    common::processes()
        .into_iter()
        .filter(|p| p.ppid == pid)
        .map(|p| p.pid)
        .collect()
}

/// Whether `pid` still runs (not gone, not a zombie waiting to be reaped).
fn running(pid: u32) -> bool {
    common::processes()
        .iter()
        .any(|p| p.pid == pid && p.running)
}

#[test]
fn sigterm_to_train_stops_every_service_it_started() {
    let dir = std::env::temp_dir().join(format!("jsae-cli-sigterm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let train = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args([
            "train",
            "--env",
            "gridworld-discrete",
            "--algo",
            "jsae",
            "--env-steps",
            "5000000",
            "--quiet",
            "--out",
            dir.to_str().unwrap_or("."),
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("jsae train starts");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let mut services = Vec::new();
    while services.len() < 3 && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(200));
        services = children_of(train.id());
    }
    assert_eq!(
        services.len(),
        3,
        "embedder, learner and actor: {services:?}"
    );
    std::thread::sleep(std::time::Duration::from_secs(2));
    let pid = rustix::process::Pid::from_child(&train);
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).expect("SIGTERM");
    let out = train.wait_with_output().expect("train ends");
    assert!(!out.status.success());
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(said.contains("stopped by a signal"), "{said}");
    let left: Vec<u32> = services.into_iter().filter(|p| running(*p)).collect();
    assert!(
        left.is_empty(),
        "still running after jsae train stopped: {left:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
