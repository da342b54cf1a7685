//! `jsae train --env gym:ID` end to end with real Python workers (the project's venv): in one
//! process, and as separate processes with two workers, one of them killed -9 mid-run (the
//! run goes on with the other and finishes; the killed worker's episodes end truncated).

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn train(out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_jsae"));
    c.args([
        "train",
        "--env",
        "gym:CartPole-v1",
        "--algo",
        "ppo",
        "--seed",
        "5",
    ])
    .args(["--out", &out.display().to_string(), "--quiet"])
    .args(extra)
    .env("JSAE_PYTHON", common::venv_python())
    .stdin(Stdio::null());
    c
}

fn summary(out: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(out.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("json")
}

#[test]
fn a_gym_environment_trains_in_one_process() {
    let out = std::env::temp_dir().join(format!("jsae-gym-one-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let status = train(&out, &["--one-process", "--env-steps", "8192"])
        .stdout(Stdio::null())
        .status()
        .expect("runs");
    assert!(status.success());
    let s = summary(&out);
    assert_eq!(s["env"], "gym");
    assert!(s["env_steps"].as_u64().is_some_and(|n| n >= 8192));
    // CartPole's time limit (500, from the environment's own description) bounds every episode
    let length = s["eval_length_mean"].as_f64().expect("eval lengths");
    assert!((1.0..=500.0).contains(&length), "{length}");
    let config = std::fs::read_to_string(out.join("config.toml")).expect("config.toml");
    assert!(config.contains("id = \"CartPole-v1\"") && config.contains("max_steps = 500"));
    assert!(out.join("logs/worker-0-0.log").is_file());
    let _ = std::fs::remove_dir_all(&out);
}

/// The pid of the worker process whose command line names `name`.
fn worker_pid(name: &str) -> Option<u32> {
    let out = Command::new("pgrep")
        .args(["-f", &format!("jsae.envs.*--name {name}( |$)")])
        .output()
        .ok()?;
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .next()
        .and_then(|l| l.trim().parse().ok())
}

#[test]
fn a_worker_killed_mid_run_leaves_the_run_to_the_other() {
    let out = std::env::temp_dir().join(format!("jsae-gym-kill-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let mut run = train(
        &out,
        &["--env-steps", "60000", "--set", "environment.gym.workers=2"],
    )
    .stdout(Stdio::null())
    .spawn()
    .expect("starts");
    // once training has begun, kill the second worker (8 of the 16 environments)
    let start = Instant::now();
    let metrics = out.join("metrics.csv");
    let killed = loop {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "training did not start"
        );
        let rows = std::fs::read_to_string(&metrics).map_or(0, |t| t.lines().count());
        if rows >= 3
            && let Some(pid) = worker_pid("worker-0-1")
        {
            break pid;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let status = Command::new("kill")
        .args(["-9", &killed.to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let finished = run.wait().expect("waits");
    assert!(finished.success(), "the run finished with the other worker");
    let s = summary(&out);
    assert!(s["env_steps"].as_u64().is_some_and(|n| n >= 60000));
    let log = std::fs::read_to_string(out.join("logs/actor-0.log")).expect("actor log");
    assert!(
        log.contains("worker-0-1") && log.contains("lost"),
        "the actor says which worker it lost:\n{log}"
    );
    assert!(out.join("logs/worker-0-0.log").is_file());
    let _ = std::fs::remove_dir_all(&out);
}
