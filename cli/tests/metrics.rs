//! Prometheus `/metrics` (`--metrics-listen`) of the learner and an actor, scraped over HTTP
//! during a real run: the env steps grow.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStderr, Command, Stdio};
use std::time::{Duration, Instant};

/// A service process, killed when dropped.
struct Service(Child);

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start(
    args: &[&str],
) -> (
    Service,
    BufReader<ChildStderr>,
    BufReader<std::process::ChildStdout>,
) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the service starts");
    let err = BufReader::new(child.stderr.take().expect("stderr"));
    let out = BufReader::new(child.stdout.take().expect("stdout"));
    (Service(child), err, out)
}

/// Reads log lines until one names the metrics address; then drains the rest in a thread.
fn metrics_address(mut err: BufReader<ChildStderr>) -> String {
    let mut line = String::new();
    loop {
        line.clear();
        assert!(
            err.read_line(&mut line).expect("reads") > 0,
            "no metrics address"
        );
        if let Some(at) = line.find("metrics on http://") {
            let rest = &line[at + "metrics on http://".len()..];
            let addr = rest.split('/').next().unwrap_or("").to_string();
            std::thread::spawn(move || for _ in err.lines() {});
            return addr;
        }
    }
}

#[test]
fn metrics_of_a_running_learner_and_actor_show_env_steps_growing() {
    let dir = std::env::temp_dir().join(format!("jsae-metrics-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = [
        "--env",
        "gridworld-discrete",
        "--algo",
        "ppo",
        "--seed",
        "4",
    ];
    let mut learner_args = vec!["learner", "--listen", "127.0.0.1:0"];
    learner_args.extend(run);
    learner_args.extend([
        "--env-steps",
        "50000000",
        "--out",
        dir.to_str().unwrap_or("."),
        "--metrics-listen",
        "127.0.0.1:0",
    ]);
    let (_learner, err, mut out) = start(&learner_args);
    let mut first = String::new();
    out.read_line(&mut first).expect("the address line");
    let url = format!("http://{}", first.trim().rsplit(' ').next().unwrap_or(""));
    let learner_metrics = metrics_address(err);

    let mut actor_args = vec!["actor", "--learner", &url, "--id", "0", "--envs", "4"];
    actor_args.extend(run);
    actor_args.extend(["--metrics-listen", "127.0.0.1:0"]);
    let (_actor, err, _out) = start(&actor_args);
    let actor_metrics = metrics_address(err);

    let deadline = Instant::now() + Duration::from_secs(120);
    let mut seen: Vec<f64> = Vec::new();
    let mut updates = 0.0;
    while seen.len() < 3 || updates < 1.0 {
        assert!(
            Instant::now() < deadline,
            "env steps did not grow: {seen:?}"
        );
        let text = common::scrape_metrics(&learner_metrics);
        updates = common::metric_value(&text, "jsae_learner_updates").unwrap_or(0.0);
        let steps =
            common::metric_value(&text, "jsae_learner_env_steps").expect("jsae_learner_env_steps");
        if steps > seen.last().copied().unwrap_or(0.0) {
            seen.push(steps);
        }
        std::thread::sleep(Duration::from_millis(300));
    }
    let text = common::scrape_metrics(&learner_metrics);
    for family in [
        "# TYPE jsae_learner_updates gauge",
        "jsae_learner_updates ",
        "jsae_learner_policy_version ",
        "jsae_learner_env_steps_per_second ",
        "jsae_learner_queue_depth ",
        "jsae_learner_fragments_dropped{reason=\"lag\"} ",
        "jsae_learner_fragments_total ",
    ] {
        assert!(text.contains(family), "{family} missing:\n{text}");
    }
    let actor = common::scrape_metrics(&actor_metrics);
    assert!(
        common::metric_value(&actor, "jsae_actor_env_steps").unwrap_or(0.0) > 0.0,
        "{actor}"
    );
    assert!(
        actor.contains("jsae_actor_queue_depth{queue=\"fragments\"}"),
        "{actor}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
