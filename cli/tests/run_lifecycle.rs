//! A run directory's life: a fresh run refuses an occupied directory unless `--force`, a
//! run's config.toml passed back with another seed makes a new run (rough edge 1), and
//! `--resume` continues a stopped run, in one process and as separate processes. Also the
//! progress of pre-training (rough edge 5) and JSON logs (rough edge 4).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn jsae_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jsae"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("jsae runs")
}

fn fresh_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("jsae-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// Small settings: short rollouts, a short pre-training, two evaluation episodes.
const SMALL: &str = "envs_per_actor = 4\nrollout_len = 32\neval_episodes = 2\n\
[embedding]\npretrain_transitions = 1000\npretrain_per_action = 0\npretrain_epochs = 20\n\
[ppo]\nepochs = 1\n";

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    err
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap_or_default())
        .expect("summary.json")
}

/// (update, env_steps) of every complete metrics.csv row (a row being written while the
/// file is read is left out).
fn rows(dir: &Path) -> Vec<(f64, f64)> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).unwrap_or_default();
    if !text.ends_with('\n') && text.contains('\n') {
        let complete = &text[..=text.rfind('\n').unwrap_or(0)];
        return rows_of(complete);
    }
    rows_of(&text)
}

fn rows_of(text: &str) -> Vec<(f64, f64)> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let Some(u) = header.iter().position(|h| *h == "update") else {
        return Vec::new();
    };
    let Some(s) = header.iter().position(|h| *h == "env_steps") else {
        return Vec::new();
    };
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            let num = |i: usize| cells[i].parse::<f64>().expect("a number");
            (num(u), num(s))
        })
        .collect()
}

fn assert_rows_go_on(dir: &Path) {
    let rows = rows(dir);
    assert!(rows.len() >= 2, "{rows:?}");
    for w in rows.windows(2) {
        assert!(w[1].0 > w[0].0 && w[1].1 > w[0].1, "rows restart: {rows:?}");
    }
}

#[test]
fn a_run_config_with_another_seed_is_a_new_run_and_old_runs_need_force() {
    let root = fresh_dir("lifecycle-dirs");
    std::fs::write(root.join("small.toml"), SMALL).expect("settings");
    let first = [
        "train",
        "--env",
        "slotmachine",
        "--algo",
        "ppo",
        "--seed",
        "1",
        "--env-steps",
        "1024",
        "--one-process",
        "--quiet",
        "--config",
        "small.toml",
        "--out",
        "seed1",
    ];
    ok(&jsae_in(&root, &first));
    let saved = std::fs::read_to_string(root.join("seed1/config.toml")).expect("config.toml");
    assert!(
        !saved.lines().any(|l| l.trim_start().starts_with("out")),
        "config.toml keeps the run directory: {saved}"
    );

    // the old run's settings with another seed: a run of its own, the old one untouched
    let again = [
        "train",
        "--config",
        "seed1/config.toml",
        "--seed",
        "2",
        "--one-process",
        "--quiet",
    ];
    ok(&jsae_in(&root, &again));
    let second = root.join("runs/slotmachine-ppo-seed2");
    assert_eq!(summary(&second)["seed"], 2);
    assert_eq!(summary(&root.join("seed1"))["seed"], 1);

    // the same directory again: refused, nothing touched, unless --force
    let stale = root.join("seed1/checkpoints/policy-v999.bpk");
    std::fs::write(&stale, b"stale").expect("stale checkpoint");
    let refused = jsae_in(&root, &first);
    assert_eq!(refused.status.code(), Some(2));
    let reason = String::from_utf8_lossy(&refused.stderr);
    assert!(
        reason.contains("--force") && reason.contains("--resume"),
        "{reason}"
    );
    assert!(stale.exists());
    let mut forced = first.to_vec();
    forced.push("--force");
    ok(&jsae_in(&root, &forced));
    assert!(
        !stale.exists(),
        "the old run's checkpoint stayed beside the new one"
    );
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn resume_continues_a_one_process_run_and_refuses_other_settings() {
    let root = fresh_dir("lifecycle-resume");
    std::fs::write(root.join("small.toml"), SMALL).expect("settings");
    let run = root.join("run");
    let base = [
        "train",
        "--env",
        "slotmachine",
        "--algo",
        "jsae",
        "--seed",
        "3",
        "--one-process",
        "--quiet",
        "--config",
        "small.toml",
        "--out",
        "run",
    ];
    let mut first = base.to_vec();
    first.extend(["--env-steps", "2048"]);
    ok(&jsae_in(&root, &first));
    let before = summary(&run);
    let rows_before = rows(&run).len();

    let other = jsae_in(&root, &["train", "--resume", "run", "--seed", "4"]);
    assert_eq!(other.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&other.stderr).contains("--seed (or JSAE_SEED) cannot change them")
    );
    let finished = jsae_in(&root, &["train", "--resume", "run", "--quiet"]);
    assert_eq!(finished.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&finished.stderr).contains("finished at"));
    let nothing = jsae_in(&root, &["train", "--resume", "nowhere"]);
    assert_eq!(nothing.status.code(), Some(2));

    let more = ["train", "--resume", "run", "--env-steps", "4096", "--quiet"];
    ok(&jsae_in(&root, &more));
    let after = summary(&run);
    assert!(after["env_steps"].as_u64().unwrap_or(0) >= 4096, "{after}");
    assert!(
        after["policy_version"].as_u64() > before["policy_version"].as_u64(),
        "{before} -> {after}"
    );
    assert!(after["embedding_version"].as_u64() >= before["embedding_version"].as_u64());
    assert!(rows(&run).len() > rows_before);
    assert_rows_go_on(&run);
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn resume_continues_a_run_of_services_stopped_by_a_signal() {
    let root = fresh_dir("lifecycle-services");
    std::fs::write(root.join("small.toml"), SMALL).expect("settings");
    let run = root.join("run");
    let train = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .current_dir(&root)
        .args([
            "--log-format",
            "json",
            "train",
            "--env",
            "gridworld-discrete",
            "--algo",
            "ppo",
            "--seed",
            "2",
            "--env-steps",
            "5000000",
            "--config",
            "small.toml",
            "--quiet",
            "--out",
            "run",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("jsae train starts");
    let deadline = Instant::now() + Duration::from_secs(120);
    while rows(&run).len() < 3 {
        assert!(Instant::now() < deadline, "no metrics rows in time");
        std::thread::sleep(Duration::from_millis(200));
    }
    let pid = rustix::process::Pid::from_child(&train);
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).expect("SIGTERM");
    let stopped = train.wait_with_output().expect("train ends");
    assert!(!stopped.status.success());
    let (last_update, last_steps) = *rows(&run).last().expect("rows");

    // the services logged JSON objects, one per line (rough edge 4)
    let log = std::fs::read_to_string(run.join("logs/learner.log")).unwrap_or_default();
    let events: Vec<&str> = log.lines().filter(|l| l.starts_with('{')).collect();
    assert!(!events.is_empty(), "{log}");
    let text_line = log.lines().find(|l| l.contains(" INFO "));
    assert!(
        text_line.is_none(),
        "a text log line in JSON mode: {text_line:?}"
    );
    for e in events {
        let v: serde_json::Value = serde_json::from_str(e).expect("a JSON log line");
        assert!(v["level"].is_string() && v["fields"].is_object(), "{e}");
    }

    let target = (last_steps as u64 + 8192).to_string();
    let resumed = jsae_in(
        &root,
        &[
            "train",
            "--resume",
            "run",
            "--env-steps",
            &target,
            "--quiet",
        ],
    );
    ok(&resumed);
    let rows = rows(&run);
    assert!(rows.iter().any(|r| r.0 > last_update), "{rows:?}");
    assert_rows_go_on(&run);
    assert!(summary(&run)["env_steps"].as_u64().unwrap_or(0) >= target.parse().unwrap_or(0));
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn pre_training_shows_its_phase_and_time_left_in_json_logs() {
    let root = fresh_dir("lifecycle-progress");
    std::fs::write(root.join("small.toml"), SMALL).expect("settings");
    let out = jsae_in(
        &root,
        &[
            "--log-format",
            "json",
            "train",
            "--env",
            "slotmachine",
            "--algo",
            "jsae",
            "--env-steps",
            "2048",
            "--one-process",
            "--config",
            "small.toml",
            "--out",
            "run",
        ],
    );
    let stderr = ok(&out);
    let messages: Vec<String> = stderr
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l)
                .unwrap_or_else(|e| panic!("not a JSON log line ({e}): {l}"));
            v["fields"]["message"].as_str().unwrap_or("").to_string()
        })
        .collect();
    let at = |prefix: &str| messages.iter().position(|m| m.starts_with(prefix));
    let random = at("random play for pre-training: ").expect("the random-play phase");
    let pretraining = messages
        .iter()
        .position(|m| {
            m.starts_with("pre-training the embedding on ") && m.contains(": epoch 1/20, about ")
        })
        .expect("pre-training with the time left");
    let first_update = at("update 1 ").expect("the first update");
    assert!(
        random < pretraining && pretraining < first_update,
        "{messages:?}"
    );
    assert!(messages[pretraining].ends_with(" s left"), "{messages:?}");
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn services_refuse_damaged_checkpoints_rather_than_start_again_over_them() {
    let dir = fresh_dir("damaged-checkpoints");
    let run = dir.join("run");
    let checkpoints = run.join("checkpoints");
    std::fs::create_dir_all(&checkpoints).expect("mkdir");
    let files = [
        "policy-latest.ckpt",
        "policy-previous.ckpt",
        "embedding-latest.ckpt",
        "embedding-previous.ckpt",
    ];
    for f in files {
        std::fs::write(checkpoints.join(f), b"torn by a crash").expect("write");
    }
    let metrics = run.join("metrics.csv");
    std::fs::write(&metrics, "update,env_steps\n1,2048\n").expect("write");
    let p = |path: &Path| path.to_str().unwrap_or(".").to_string();
    let common = [
        "--env",
        "gridworld-discrete",
        "--algo",
        "jsae",
        "--seed",
        "1",
        "--listen",
        "127.0.0.1:0",
    ];
    let learner = jsae_in(
        &dir,
        &[&["learner", "--out", &p(&run)], &common[..]].concat(),
    );
    let embedder = jsae_in(
        &dir,
        &[
            &["embedder", "--checkpoint-dir", &p(&checkpoints)],
            &common[..],
        ]
        .concat(),
    );
    for (out, kind) in [(learner, "policy"), (embedder, "embedding")] {
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{kind}: {err}");
        for file in [
            format!("{kind}-latest.ckpt"),
            format!("{kind}-previous.ckpt"),
        ] {
            assert!(err.contains(&file), "{kind}: {err}");
        }
    }
    // nothing was overwritten
    for f in files {
        let bytes = std::fs::read(checkpoints.join(f)).expect("kept");
        assert_eq!(bytes, b"torn by a crash", "{f}");
    }
    let kept = std::fs::read_to_string(&metrics).expect("kept");
    assert_eq!(kept, "update,env_steps\n1,2048\n");
    let _ = std::fs::remove_dir_all(&dir);
}

/// SIGTERM while a learner builds a large model (4,096 x 4,096, within the settings' bounds,
/// tens of seconds to build here) stops it within seconds, not at the end of the build.
#[test]
fn a_learner_building_a_large_model_stops_on_sigterm() {
    let root = fresh_dir("lifecycle-large-model");
    std::fs::write(root.join("large.toml"), "[ppo]\nhidden = [4096, 4096]\n").expect("settings");
    let learner = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .current_dir(&root)
        .args(["learner", "--listen", "127.0.0.1:0", "--env", "gridworld"])
        .args(["--algo", "ppo", "--config", "large.toml", "--out", "run"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("the learner starts");
    std::thread::sleep(Duration::from_secs(3));
    let pid = rustix::process::Pid::from_child(&learner);
    let signalled = Instant::now();
    rustix::process::kill_process(pid, rustix::process::Signal::TERM).expect("SIGTERM");
    let stopped = learner.wait_with_output().expect("the learner ends");
    let log = String::from_utf8_lossy(&stopped.stderr);
    assert!(
        signalled.elapsed() < Duration::from_secs(15),
        "{:?} after SIGTERM: {log}",
        signalled.elapsed()
    );
    assert!(
        log.contains("stopped while building the model") || log.contains("interrupted"),
        "{log}"
    );
}
