//! The per-service binaries are the `jsae` subcommands: the same flags, the same refusals, the
//! same behaviour (`jsae-learner` reads a recommender run's logged purchases as `jsae learner`
//! does), and with `--log-format json` every line a service writes is a JSON object.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The flags a `--help` text lists (`--name` at the start of a line, after spaces).
fn flags(help: &[u8]) -> Vec<String> {
    let mut flags: Vec<String> = String::from_utf8_lossy(help)
        .lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let l = l.split_once("--").map(|(before, after)| {
                (before.is_empty() || before.ends_with(", ")).then_some(after)
            })??;
            Some(
                l.split(|c: char| !(c.is_alphanumeric() || c == '-'))
                    .next()?
                    .to_string(),
            )
        })
        .collect();
    flags.sort();
    flags
}

#[test]
fn each_service_binary_takes_its_subcommands_flags() {
    for (bin, sub) in [
        (env!("CARGO_BIN_EXE_jsae-learner"), "learner"),
        (env!("CARGO_BIN_EXE_jsae-embedder"), "embedder"),
        (env!("CARGO_BIN_EXE_jsae-actor"), "actor"),
    ] {
        let own = Command::new(bin).arg("--help").output().expect("runs");
        let via = Command::new(env!("CARGO_BIN_EXE_jsae"))
            .args([sub, "--help"])
            .output()
            .expect("runs");
        assert!(own.status.success() && via.status.success(), "{sub}");
        let (own, via) = (flags(&own.stdout), flags(&via.stdout));
        assert!(own.contains(&"log-format".to_string()), "{sub}: {own:?}");
        assert_eq!(own, via, "{sub}");
    }
}

fn all_json(text: &[u8], what: &str) {
    for line in String::from_utf8_lossy(text).lines() {
        assert!(
            serde_json::from_str::<serde_json::Value>(line).is_ok_and(|v| v.is_object()),
            "{what}: not a JSON object: {line:?}"
        );
    }
}

#[test]
fn with_json_logs_every_line_a_service_writes_is_json() {
    // refusals before the service runs: a settings file that is not there, a missing flag
    for missing in [&["--listen", "127.0.0.1:0"][..], &[]] {
        let bad = Command::new(env!("CARGO_BIN_EXE_jsae-learner"))
            .args(["--log-format", "json", "--config", "/nonexistent/run.toml"])
            .args(["--seed", "1", "--out", "/nonexistent/x"])
            .args(missing)
            .output()
            .expect("runs");
        assert_eq!(bad.status.code(), Some(2));
        assert!(!bad.stderr.is_empty());
        all_json(&bad.stderr, "refusal");
    }

    // the address it listens on, then its log until SIGTERM
    let dir = std::env::temp_dir().join(format!("jsae-json-logs-{}", std::process::id()));
    let (mut child, first) = learner_listening(
        &[
            "--log-format",
            "json",
            "--env",
            "gridworld-discrete",
            "--algo",
            "ppo",
        ],
        &dir,
        Stdio::piped(),
    );
    let event: serde_json::Value = serde_json::from_str(&first).expect("a JSON line");
    let address = event["fields"]["address"].as_str().unwrap_or_default();
    assert!(address.starts_with("127.0.0.1:"), "{first}");
    assert!(
        Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .is_ok_and(|s| s.success())
    );
    let deadline = Instant::now() + Duration::from_secs(20);
    while child.try_wait().expect("waits").is_none() {
        assert!(Instant::now() < deadline, "ignored SIGTERM");
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = child.wait_with_output().expect("ends");
    assert!(!out.stderr.is_empty());
    all_json(&out.stderr, "stderr");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn jsae_learner_reads_a_recommender_runs_logged_purchases_as_jsae_learner_does() {
    // the recommender's PPO counts its prior from the logs: the binary used to refuse it
    let dir = std::env::temp_dir().join(format!("jsae-learner-logs-{}", std::process::id()));
    let (mut child, first) = learner_listening(
        &["--env", "recommender", "--algo", "ppo"],
        &dir,
        Stdio::null(),
    );
    let _ = child.kill();
    let _ = child.wait();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        first.contains("jsae-learner listening on 127.0.0.1:"),
        "{first:?}"
    );
}

/// `jsae-learner ARGS --seed 1 --listen 127.0.0.1:0 --out DIR` started, with the first line
/// it wrote on stdout.
fn learner_listening(
    args: &[&str],
    dir: &std::path::Path,
    stderr: Stdio,
) -> (std::process::Child, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_jsae-learner"))
        .args(args)
        .args(["--seed", "1", "--listen", "127.0.0.1:0", "--out"])
        .arg(dir)
        .stdout(Stdio::piped())
        .stderr(stderr)
        .spawn()
        .expect("starts");
    let mut first = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut first)
        .expect("reads");
    (child, first)
}
