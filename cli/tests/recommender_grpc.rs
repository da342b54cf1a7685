//! The Recommender service from another language: a short JSAE run on synthetic sessions,
//! then `jsae recommender --run DIR` serves its policy and a Python grpcio client (stubs
//! generated from wire/proto/ at test time, scripts/python/recommender_client.py) submits good
//! and malformed sessions and asks for recommendations, good and bad. Then the session
//! store holds exactly the good sessions, and once the model is refreshed from it a
//! submitted new item is known to `Recommend`. The command-line clients (`jsae recommend`,
//! `jsae submit-sessions`) are checked against the same service.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use common::{Server, python_json, start_recommender};
use jsae_wire::pb;

const SETTINGS: &str = r#"
env = "recommender"
algo = "jsae"
env_steps = 8192
envs_per_actor = 8
rollout_len = 64
eval_episodes = 2
[environment.recommender]
source = "synthetic"
top_n = 50
refresh_seconds = 1
[environment.recommender.synthetic]
items = 40
sessions = 2000
[embedding]
pretrain_transitions = 2048
pretrain_epochs = 2
state_dim = 16
action_dim = 16
[embedding.recommender]
pair_buckets = 4096
logged_pretrain_epochs = 1
[ppo]
epochs = 2
"#;

fn recommend(url: &str, history: &[&str], k: u32) -> Result<pb::RecommendResponse, tonic::Status> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        let mut client = pb::recommender_client::RecommenderClient::connect(url.to_owned())
            .await
            .map_err(|e| tonic::Status::unavailable(e.to_string()))?;
        client
            .recommend(pb::RecommendRequest {
                history: history.iter().map(|h| (*h).to_owned()).collect(),
                k,
            })
            .await
            .map(tonic::Response::into_inner)
    })
}

#[test]
fn a_python_client_submits_sessions_and_gets_recommendations() {
    let dir = std::env::temp_dir().join(format!("jsae-recommender-grpc-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let settings = dir.join("settings.toml");
    std::fs::write(&settings, SETTINGS).expect("settings");
    let run = dir.join("run");
    let store = dir.join("store");
    train_small_run(&settings, &run);

    let mut args: Vec<std::ffi::OsString> = vec!["--run".into(), run.clone().into()];
    args.extend(["--store-dir".into(), store.clone().into()]);
    let (server, addr) = start_recommender(&args);

    // the container healthcheck's command
    let health = |service: &str| {
        Command::new(env!("CARGO_BIN_EXE_jsae"))
            .args(["health", "--addr", &addr, "--service", service])
            .output()
            .expect("jsae health runs")
    };
    assert!(health("jsae.v1.Recommender").status.success());
    assert!(health("").status.success());
    assert_eq!(health("jsae.v1.Nothing").status.code(), Some(1));

    python_client_checks(&addr, &store);
    command_line_client_checks(&dir, &addr, &store);
    // the refresh (every second here) puts the new items into free catalogue slots
    let url = format!("http://{addr}");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let r = recommend(&url, &["brand-new-item", "cli-new-item"], 3).expect("Recommend answers");
        if r.unknown_items == 0 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the submitted item never joined the model"
        );
        std::thread::sleep(Duration::from_millis(200));
    }

    // a request over MAX_REQUEST_BYTES (4 MiB) is RESOURCE_EXHAUSTED, as the service's own
    // limits are (tonic alone says OUT_OF_RANGE)
    let long: Vec<String> = (0..50_000).map(|i| format!("{i:0>100}")).collect();
    let history: Vec<&str> = long.iter().map(String::as_str).collect();
    let refused = recommend(&url, &history, 3).expect_err("a 5 MB request");
    assert_eq!(
        refused.code(),
        tonic::Code::ResourceExhausted,
        "{refused:?}"
    );

    stop_with_sigterm(server);
    assert_eq!(
        health("").status.code(),
        Some(1),
        "nothing answers any more"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `jsae train --one-process` of the small settings into `run`.
fn train_small_run(settings: &Path, run: &Path) {
    let trained = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["train", "--one-process", "--quiet", "--config"])
        .arg(settings)
        .arg("--out")
        .arg(run)
        .output()
        .expect("jsae train runs");
    assert!(
        trained.status.success(),
        "{}",
        String::from_utf8_lossy(&trained.stderr)
    );
}

/// The Python client (`scripts/python/recommender_client.py`): recommendations, the errors of
/// the sessions it submits, and exactly its two good sessions stored.
fn python_client_checks(addr: &str, store: &Path) {
    let seen = python_json(
        "recommender_client.py",
        &[addr, "item-0", "item-1", "item-2"],
    );
    assert!(seen["recommend"]["policy_version"].as_u64() > Some(0));
    assert!(seen["recommend"]["embedding_version"].as_u64() > Some(0));
    let errors: Vec<String> = seen["submit"]["errors"]
        .as_array()
        .expect("errors")
        .iter()
        .filter_map(|e| e.as_str().map(str::to_owned))
        .collect();
    for reason in [
        "session_id is empty",
        "no purchases",
        "item_id is empty",
        "price",
    ] {
        assert!(
            errors.iter().any(|e| e.contains(reason)),
            "no error says {reason:?}: {errors:?}"
        );
    }
    assert!(
        seen["invalid"]["k_above_catalogue"]
            .as_str()
            .is_some_and(|m| m.contains("catalogue")),
        "{seen}"
    );

    // exactly the two good sessions were stored, synced before the answer
    let stored = std::fs::read_to_string(store.join("sessions.jsonl")).expect("the store");
    let ids: Vec<String> = stored
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).expect("JSON line")["session_id"]
                .as_str()
                .unwrap_or_default()
                .to_owned()
        })
        .collect();
    assert_eq!(ids, ["good-1", "good-2"]);
}

/// `jsae recommend`, and `jsae submit-sessions` with one good session holding a new item and
/// one the service refuses, then a file that is not a session file.
fn command_line_client_checks(dir: &Path, addr: &str, store: &Path) {
    let asked = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["recommend", "--addr", addr, "--k", "2", "item-0", "item-1"])
        .output()
        .expect("jsae recommend runs");
    assert!(
        asked.status.success(),
        "{}",
        String::from_utf8_lossy(&asked.stderr)
    );
    let answer: serde_json::Value = serde_json::from_slice(&asked.stdout).expect("JSON");
    assert_eq!(
        answer["items"].as_array().map(Vec::len),
        Some(2),
        "{answer}"
    );
    let lines = dir.join("more.jsonl");
    std::fs::write(
        &lines,
        concat!(
            r#"{"session_id": "cli-1", "purchases": [{"item_id": "item-3"}, {"item_id": "cli-new-item", "price": 2.5}]}"#,
            "\n",
            r#"{"session_id": "cli-bad", "purchases": []}"#,
            "\n"
        ),
    )
    .expect("session file");
    let submitted = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["submit-sessions", "--addr", addr])
        .arg(&lines)
        .output()
        .expect("jsae submit-sessions runs");
    assert_eq!(submitted.status.code(), Some(1), "one was rejected");
    let summary: serde_json::Value =
        serde_json::from_slice(&submitted.stdout).expect("the summary as JSON");
    assert_eq!(summary["sessions_accepted"], 1, "{summary}");
    assert_eq!(summary["sessions_rejected"], 1, "{summary}");
    assert_eq!(summary["purchases_accepted"], 2, "{summary}");
    assert!(
        summary["errors"][0]
            .as_str()
            .is_some_and(|e| e.starts_with("session 1 (session_id \"cli-bad\")")
                && e.contains("no purchases")),
        "{summary}"
    );
    // a file that is not a session file: exit 2 naming the line, nothing sent
    let broken = dir.join("broken.jsonl");
    std::fs::write(
        &broken,
        "{\"session_id\": \"cli-2\", \"purchases\": [{\"item_id\": \"x\"}]}\n{oops\n",
    )
    .expect("broken file");
    let refused = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["submit-sessions", "--addr", addr])
        .arg(&broken)
        .output()
        .expect("jsae submit-sessions runs");
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("broken.jsonl:2:"));
    let stored = std::fs::read_to_string(store.join("sessions.jsonl")).expect("the store");
    assert_eq!(stored.lines().count(), 3, "good-1, good-2, cli-1: {stored}");
    assert!(
        stored
            .lines()
            .last()
            .is_some_and(|l| l.contains("cli-new-item"))
    );
}

/// SIGTERM to the Recommender: it exits 0.
fn stop_with_sigterm(server: Server) {
    let pid = server.0.id().to_string();
    let killed = Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .expect("kill");
    assert!(killed.success());
    let mut server = server;
    let deadline = Instant::now() + Duration::from_secs(10);
    let status = loop {
        if let Some(s) = server.0.try_wait().expect("wait") {
            break s;
        }
        assert!(Instant::now() < deadline, "no exit after SIGTERM");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{status:?}");
}

/// `--policy most-likely|item-knn|popular` need no run: each answers the Python client with
/// its own ranking (the library's, from the same data), and only popular ignores the history.
#[test]
fn the_reference_policies_are_served_to_a_python_client() {
    use jsae_recommender::Recommender;
    use jsae_recommender::baseline::PolicyChoice;

    let dir = std::env::temp_dir().join(format!("jsae-recommender-ref-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let settings = dir.join("settings.toml");
    std::fs::write(&settings, SETTINGS).expect("settings");
    let config = jsae_settings::TrainConfig::from_layers(None, None, Some(&settings))
        .expect("settings parse");
    let ask = |addr: &str, history: &[&str]| -> Vec<String> {
        let answer = python_json(
            "recommender_client.py",
            &[&["--ask", addr, "5"][..], history].concat(),
        );
        assert_eq!(answer["policy_version"], 0, "{answer}");
        answer["items"]
            .as_array()
            .expect("items")
            .iter()
            .map(|i| i.as_str().expect("an id").to_owned())
            .collect()
    };
    let (first, second) = (["item-0", "item-1"], ["item-5", "item-2"]);
    for (name, choice) in [
        ("most-likely", PolicyChoice::MostLikely),
        ("item-knn", PolicyChoice::ItemKnn),
        ("popular", PolicyChoice::Popular),
    ] {
        let mut args: Vec<std::ffi::OsString> = vec!["--policy".into(), name.into()];
        args.extend(["--config".into(), settings.clone().into()]);
        let metrics = format!("127.0.0.1:{}", common::free_port());
        args.extend(["--metrics-listen".into(), metrics.clone().into()]);
        let (_server, addr) = start_recommender(&args);
        let library = Recommender::new(&config, choice, jsae_nn::DeviceKind::Flex)
            .expect("the same recommender in process");
        let expected = |history: &[&str]| -> Vec<String> {
            let history: Vec<String> = history.iter().map(|h| (*h).to_owned()).collect();
            let r = library.recommend(&history, 5).expect("ranks");
            r.items.into_iter().map(|(id, _)| id).collect()
        };
        let (a, b) = (ask(&addr, &first), ask(&addr, &second));
        assert_eq!(a, expected(&first), "{name}");
        assert_eq!(b, expected(&second), "{name}");
        assert_eq!(
            a == b,
            choice == PolicyChoice::Popular,
            "{name}: {a:?} {b:?}"
        );
        // Prometheus: both calls in the latency histogram and the request counter
        let text = common::scrape_metrics(&metrics);
        let count = common::metric_value(&text, "jsae_recommender_recommend_seconds_count");
        assert_eq!(count, Some(2.0), "{text}");
        let ok = r#"jsae_recommender_requests_total{rpc="recommend",code="ok"}"#;
        assert_eq!(common::metric_value(&text, ok), Some(2.0), "{text}");
    }
    // a reference policy follows no learner
    let out = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args([
            "recommender",
            "--policy",
            "popular",
            "--learner",
            "http://127.0.0.1:1",
        ])
        .output()
        .expect("jsae runs");
    assert_eq!(out.status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_recommender_command_line_refuses_incomplete_input() {
    let out = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args(["recommender", "--listen", "127.0.0.1:0"])
        .output()
        .expect("jsae runs");
    assert_eq!(out.status.code(), Some(2));
    let reason = String::from_utf8_lossy(&out.stderr);
    assert!(
        reason.contains("--learner") && reason.contains("--run"),
        "{reason}"
    );

    let out = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .args([
            "recommender",
            "--learner",
            "http://127.0.0.1:1",
            "--algo",
            "jsae",
        ])
        .output()
        .expect("jsae runs");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--embedder"));

    // a run that is not there: exit 2 unless asked to wait (rough edge 8)
    let run = |dir: &str| {
        Command::new(env!("CARGO_BIN_EXE_jsae"))
            .args(["recommender", "--listen", "127.0.0.1:0", "--run", dir])
            .output()
            .expect("jsae runs")
    };
    let missing = run("/nonexistent/run");
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("--wait"));
    // a run of another environment: exit 2, not "shape mismatch" forever
    let dir = std::env::temp_dir().join(format!("jsae-rec-kind-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    std::fs::write(dir.join("config.toml"), "env = \"gridworld-discrete\"\n").expect("config");
    let other = run(dir.to_str().unwrap_or_default());
    assert_eq!(other.status.code(), Some(2));
    let reason = String::from_utf8_lossy(&other.stderr);
    assert!(reason.contains("not a recommender run"), "{reason}");
    let _ = std::fs::remove_dir_all(&dir);
}
