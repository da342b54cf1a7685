//! `jsae train --record`: the MCAP file reads back through the Python `mcap` reader (its
//! protobuf decoder, the schema inside the file) transition for transition, its episodes
//! chain, `jsae record-info` summarises it, and `--pretrain-from` it pre-trains another
//! seed's embedding to within 10% of that seed's own random play of the same size. The run's
//! metrics are read back from its TensorBoard files by TensorBoard's own reader.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{assert_tensorboard_holds_the_metrics, repo_root, stderr_within, venv_python};
use serde_json::Value;

fn jsae(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(args)
        .output()
        .expect("jsae runs")
}

fn ok(out: &std::process::Output) -> String {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Pre-training on exactly 4 rollouts of 16 environments x 64 steps: the fresh run and the
/// recording's first transitions are the same size.
const CONFIG: &str = "envs_per_actor = 16\nrollout_len = 64\neval_episodes = 2\n\
[embedding]\npretrain_transitions = 4096\npretrain_per_action = 0\npretrain_epochs = 10\n\
[ppo]\nepochs = 1\n";

fn train(dir: &Path, seed: u64, extra: &[&str]) -> String {
    let cfg = dir.join("settings.toml");
    std::fs::write(&cfg, CONFIG).expect("config");
    let out = dir.join(format!("run-{seed}-{}", extra.len()));
    let seed = seed.to_string();
    let mut args = vec![
        "train",
        "--env",
        "gridworld-discrete",
        "--algo",
        "jsae",
        "--seed",
        &seed,
        "--env-steps",
        "8192",
        "--one-process",
        "--quiet",
        "--config",
        cfg.to_str().unwrap_or_default(),
        "--out",
        out.to_str().unwrap_or_default(),
    ];
    args.extend_from_slice(extra);
    ok(&jsae(&args));
    out.display().to_string()
}

/// The model loss of the first embedding, from the run's metrics.csv.
fn first_embedding_loss(run: &str) -> f64 {
    let text = std::fs::read_to_string(Path::new(run).join("metrics.csv")).expect("metrics");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
    let (version, loss) = (col("embedding_version"), col("embedding_loss"));
    lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .find(|row| row[version] == "1")
        .and_then(|row| row[loss].parse().ok())
        .expect("a row with embedding v1")
}

/// A proto3 JSON integer (64-bit ones are strings).
fn int(v: &Value) -> u64 {
    v.as_u64()
        .or_else(|| v.as_str().and_then(|s| s.parse().ok()))
        .unwrap_or(u64::MAX)
}

#[test]
fn a_recording_reads_back_in_python_and_pretrains_another_run() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("jsae-record-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("dir");
    let file = dir.join("recordings/seed5.mcap");
    let file_arg = file.to_str().unwrap_or_default();
    let run = train(&dir, 5, &["--record", file_arg]);
    let summary: Value = serde_json::from_str(
        &std::fs::read_to_string(Path::new(&run).join("summary.json")).expect("summary"),
    )
    .expect("json");

    // The run's metrics are in TensorBoard's files too.
    assert_tensorboard_holds_the_metrics(Path::new(&run));

    // The third-party reader, with the schema from the file.
    let dump = Command::new(venv_python())
        .arg(repo_root().join("scripts/python/mcap_dump.py"))
        .arg(&file)
        .output()
        .expect("python runs");
    let text = ok(&dump);
    let mut lines = text.lines();
    let channel: Value = serde_json::from_str(lines.next().expect("channel")).expect("json");
    assert_eq!(channel["schema"], "jsae.record.v1.Transition");
    assert_eq!(channel["message_encoding"], "protobuf");
    assert_eq!(channel["metadata"]["env"], "gridworld-discrete");
    let rows: Vec<Value> = lines
        .map(|l| serde_json::from_str(l).expect("row"))
        .collect();

    // Transition for transition what this crate's reader returns, and every step the run took.
    let ours = jsae_record::read(&file, None).expect("our reader");
    assert!(ours.finished);
    assert_eq!(rows.len(), ours.transitions.len());
    assert_eq!(
        rows.len() as u64,
        summary["env_steps"].as_u64().unwrap_or(0)
    );
    for (py, t) in rows.iter().zip(&ours.transitions) {
        same_transition(py, t);
    }
    episodes_chain(&rows);
    let info: Value = serde_json::from_str(&ok(&jsae(&["record-info", file_arg]))).expect("json");
    assert_eq!(info["transitions"].as_u64(), Some(rows.len() as u64));
    let random = info["random_play"].as_u64().unwrap_or(0);
    assert!(random >= 4096 && random < rows.len() as u64, "{info}");
    assert_eq!(info["environments"].as_u64(), Some(16));
    let bad = jsae(&["record-info", run.as_str()]);
    assert_eq!(bad.status.code(), Some(2));

    // Another seed pre-trained on seed 5's random play, against its own random play.
    let fresh = first_embedding_loss(&train(&dir, 6, &[]));
    let recorded = first_embedding_loss(&train(&dir, 6, &["--pretrain-from", file_arg]));
    let ratio = recorded / fresh;
    eprintln!("model loss after pre-training: fresh {fresh:.4}, from the recording {recorded:.4}");
    assert!(
        (0.9..=1.1).contains(&ratio),
        "fresh {fresh}, recorded {recorded}"
    );

    other_environments_recording_is_refused(&dir, file_arg);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A row of the Python reader's against the same transition read by this crate's reader.
fn same_transition(py: &Value, t: &jsae_record::pb::Transition) {
    let cats: Vec<u64> = py["state_categories"]
        .as_array()
        .expect("state")
        .iter()
        .map(int)
        .collect();
    let next: Vec<u64> = py["next_state_categories"]
        .as_array()
        .expect("next")
        .iter()
        .map(int)
        .collect();
    assert_eq!(
        cats,
        t.state_categories
            .iter()
            .map(|&c| u64::from(c))
            .collect::<Vec<_>>()
    );
    assert_eq!(
        next,
        t.next_state_categories
            .iter()
            .map(|&c| u64::from(c))
            .collect::<Vec<_>>()
    );
    assert_eq!(
        int(&py["discrete_action"]),
        u64::from(t.discrete_action.unwrap_or(u32::MAX))
    );
    assert_eq!(py["reward"].as_f64().map(|r| r as f32), Some(t.reward));
    assert_eq!(
        (int(&py["env_index"]), int(&py["episode"]), int(&py["step"])),
        (u64::from(t.env_index), t.episode, u64::from(t.step))
    );
    assert_eq!(
        (py["terminated"].as_bool(), py["truncated"].as_bool()),
        (Some(t.terminated), Some(t.truncated))
    );
    assert_eq!(
        (int(&py["policy_version"]), int(&py["embedding_version"])),
        (t.policy_version, t.embedding_version)
    );
    assert_eq!(py["run_id"], "run-5-2");
}

/// Episodes chain: within an environment, each step starts where the last one ended, unless
/// the last one ended its episode; then the next is step 0 of the next episode. Some episode
/// was cut, and random play came first, then the policy's.
fn episodes_chain(rows: &[Value]) {
    let mut last: std::collections::HashMap<u64, &Value> = std::collections::HashMap::new();
    for row in rows {
        let env = int(&row["env_index"]);
        if let Some(prev) = last.get(&env) {
            let ended = prev["terminated"] == true || prev["truncated"] == true;
            if ended {
                assert_eq!(
                    (int(&row["step"]), int(&row["episode"])),
                    (0, int(&prev["episode"]) + 1)
                );
            } else {
                assert_eq!(row["state_categories"], prev["next_state_categories"]);
                assert_eq!(int(&row["step"]), int(&prev["step"]) + 1);
            }
        }
        last.insert(env, row);
    }
    assert!(
        rows.iter().any(|r| r["truncated"] == true),
        "no episode was cut"
    );
    // random play first, then the policy's
    assert_eq!(int(&rows[0]["policy_version"]), 0);
    assert!(int(&rows[rows.len() - 1]["policy_version"]) > 0);
}

/// A recording of another environment is refused before training, in one process and as
/// separate processes: there the embedder stops with the cause and `jsae train` says it (it
/// used to wait for ever while the actor played at random); PPO takes no recording.
fn other_environments_recording_is_refused(dir: &Path, file_arg: &str) {
    let wrong = |out: &str, one_process: bool| {
        let out = dir.join(out);
        let mut args = vec![
            "train",
            "--env",
            "gridworld",
            "--algo",
            "jsae",
            "--env-steps",
            "30000",
            "--quiet",
            "--pretrain-from",
            file_arg,
            "--out",
            out.to_str().unwrap_or_default(),
        ];
        if one_process {
            args.push("--one-process");
        }
        let mut command = Command::new(env!("CARGO_BIN_EXE_jsae"));
        command.args(args);
        let done = stderr_within(&mut command, 120, "jsae train still waits");
        assert!(!done.status.success());
        String::from_utf8_lossy(&done.stderr).into_owned()
    };
    let err = wrong("wrong", true);
    assert!(err.contains("not of this run's spaces"), "{err}");
    let err = wrong("wrong-separate", false);
    assert!(
        err.contains("the embedder exited") && err.contains("not of this run's spaces"),
        "{err}"
    );
    let ppo = jsae(&["train", "--algo", "ppo", "--pretrain-from", file_arg]);
    assert_eq!(ppo.status.code(), Some(2));
}
