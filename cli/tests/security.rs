//! The deployment's token and TLS from the outside, as users run them: `jsae train` as
//! separate processes with mutual TLS and a token trains to the end; a Python grpcio client
//! is refused without the token (and with a wrong one) on every RPC but health of the
//! Recommender (over plain text and over TLS), the embedder and the learner; bad security
//! flags stop a service at start with exit 2.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{Server, free_port, python_json, start_recommender};
use jsae_net::security::test_certs::TestPki;

/// A deployment's token (32 hex characters).
const TOKEN: &str = "3f9a0c5e7b1d2f4a6c8e0b2d4f6a8c0e";

fn fresh_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("jsae-security-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn token_file(dir: &Path) -> PathBuf {
    let path = dir.join("token");
    std::fs::write(&path, format!("{TOKEN}\n")).expect("token file");
    path
}

fn jsae(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jsae"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("jsae runs")
}

fn arg(path: &Path) -> &str {
    path.to_str().expect("a UTF-8 path")
}

#[test]
fn services_with_mutual_tls_and_a_token_train_to_the_end() {
    let dir = fresh_dir("train");
    let pki = TestPki::generate(&dir, "run").expect("a throw-away CA");
    let token = token_file(&dir);
    std::fs::write(
        dir.join("small.toml"),
        "envs_per_actor = 4\nrollout_len = 32\neval_episodes = 2\n\
         [embedding]\npretrain_transitions = 1000\npretrain_per_action = 0\n\
         pretrain_epochs = 5\n[ppo]\nepochs = 1\n",
    )
    .expect("settings");
    let out = jsae(
        &dir,
        &[
            "train",
            "--env",
            "gridworld-discrete",
            "--algo",
            "jsae",
            "--seed",
            "3",
            "--env-steps",
            "4096",
            "--config",
            "small.toml",
            "--quiet",
            "--out",
            "run",
            "--auth-token-file",
            arg(&token),
            "--tls-cert",
            arg(&pki.cert),
            "--tls-key",
            arg(&pki.key),
            "--tls-ca",
            arg(&pki.ca),
            "--tls-client-ca",
            arg(&pki.ca),
        ],
    );
    let logs = |name: &str| std::fs::read_to_string(dir.join("run/logs").join(name));
    assert!(
        out.status.success(),
        "{}\nlearner: {:?}\nactor: {:?}",
        String::from_utf8_lossy(&out.stderr),
        logs("learner.log"),
        logs("actor-0.log")
    );
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("run/summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    assert!(
        summary["env_steps"].as_u64().unwrap_or(0) >= 4096,
        "{summary}"
    );
    assert!(
        summary["embedding_version"].as_u64().unwrap_or(0) >= 1,
        "{summary}"
    );
    let learner = logs("learner.log").unwrap_or_default();
    assert!(!learner.contains(TOKEN), "the token was logged");

    // a TLS identity without a CA to trust it cannot work between the services
    let lone = jsae(
        &dir,
        &[
            "train",
            "--env",
            "gridworld-discrete",
            "--algo",
            "ppo",
            "--out",
            "other",
            "--tls-cert",
            arg(&pki.cert),
            "--tls-key",
            arg(&pki.key),
        ],
    );
    assert_eq!(lone.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&lone.stderr).contains("--tls-ca"));
}

/// `jsae recommender --policy popular` on synthetic sessions with `extra` flags; the server
/// and its `host:port`.
fn recommender_with(dir: &Path, extra: &[&str]) -> (Server, String) {
    let settings = dir.join("recommender.toml");
    std::fs::write(
        &settings,
        "env = \"recommender\"\n[environment.recommender]\nsource = \"synthetic\"\n\
         [environment.recommender.synthetic]\nitems = 40\nsessions = 500\n",
    )
    .expect("settings");
    let args = [
        &["--policy", "popular", "--config", arg(&settings)][..],
        extra,
    ]
    .concat();
    start_recommender(&args)
}

/// Runs the Python client's token check against `addr` (`ca`: "-" for plain text).
fn python_auth_check(addr: &str, token: &Path, ca: &str) -> serde_json::Value {
    python_json(
        "recommender_client.py",
        &["--auth", addr, arg(token), ca, "item-0"],
    )
}

#[test]
fn a_python_client_needs_the_token_on_every_rpc_but_health() {
    let dir = fresh_dir("python");
    let token = token_file(&dir);
    let (_plain, addr) = recommender_with(&dir, &["--auth-token-file", arg(&token)]);
    let seen = python_auth_check(&addr, &token, "-");
    for call in ["recommend", "submit", "reflection"] {
        assert!(seen[format!("{call}_without_token")].is_string(), "{seen}");
        assert!(seen[format!("{call}_wrong_token")].is_string(), "{seen}");
    }
    assert_eq!(seen["health"], "SERVING");

    let pki = TestPki::generate(&dir, "rec").expect("a throw-away CA");
    let tls = [
        "--auth-token-file",
        arg(&token),
        "--tls-cert",
        arg(&pki.cert),
        "--tls-key",
        arg(&pki.key),
    ];
    let (_secure, addr) = recommender_with(&dir, &tls);
    let port = addr.rsplit(':').next().expect("a port");
    let seen = python_auth_check(&format!("localhost:{port}"), &token, arg(&pki.ca));
    assert_eq!(seen["reflection_with_token"], "answered", "{seen}");

    // the command-line client: refused without the token, answered with it
    let url = format!("https://localhost:{port}");
    let ask = [
        "recommend",
        "--addr",
        &url,
        "--tls-ca",
        arg(&pki.ca),
        "item-0",
    ];
    let refused = jsae(&dir, &ask);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("Unauthenticated"));
    let answered = jsae(
        &dir,
        &[&ask[..], &["--auth-token-file", arg(&token)]].concat(),
    );
    assert!(
        answered.status.success(),
        "{}",
        String::from_utf8_lossy(&answered.stderr)
    );
    let health = jsae(&dir, &["health", "--addr", &url, "--tls-ca", arg(&pki.ca)]);
    assert!(
        health.status.success(),
        "{}",
        String::from_utf8_lossy(&health.stderr)
    );
}

/// `jsae SERVICE --listen 127.0.0.1:PORT` with `args`, its output in `dir/SERVICE.log`.
fn start_service(dir: &Path, service: &str, port: u16, args: &[&str]) -> Server {
    let log = std::fs::File::create(dir.join(format!("{service}.log"))).expect("log file");
    let child = Command::new(env!("CARGO_BIN_EXE_jsae"))
        .current_dir(dir)
        .args([service, "--listen", &format!("127.0.0.1:{port}")])
        .args(args)
        .stdout(log.try_clone().expect("log file"))
        .stderr(log)
        .spawn()
        .expect("the service starts");
    Server(child)
}

#[test]
fn a_python_client_needs_the_token_on_every_embedder_and_learner_rpc_but_health() {
    let dir = fresh_dir("python-services");
    let token = token_file(&dir);
    let (embedder_port, learner_port) = (free_port(), free_port());
    let run = [
        "--env",
        "gridworld-discrete",
        "--algo",
        "jsae",
        "--seed",
        "1",
    ];
    let secured = ["--auth-token-file", arg(&token)];
    let _embedder = start_service(
        &dir,
        "embedder",
        embedder_port,
        &[&run[..], &secured].concat(),
    );
    let embedder_url = format!("http://127.0.0.1:{embedder_port}");
    let learner_args = ["--embedder", &embedder_url, "--out", "run"];
    let _learner = start_service(
        &dir,
        "learner",
        learner_port,
        &[&run[..], &secured, &learner_args].concat(),
    );
    let seen = python_json(
        "services_auth_check.py",
        &[
            &format!("127.0.0.1:{embedder_port}"),
            &format!("127.0.0.1:{learner_port}"),
            arg(&token),
        ],
    );
    println!("{seen}");
    let rpcs = [
        "embedder/PushTransitions",
        "embedder/WatchEmbedding",
        "embedder/HoldEmbedding",
        "embedder/reflection",
        "learner/PushFragments",
        "learner/WatchPolicy",
        "learner/ReportEval",
        "learner/reflection",
    ];
    for rpc in rpcs {
        for label in ["without_token", "wrong_token"] {
            assert_eq!(seen[format!("{rpc} {label}")], "UNAUTHENTICATED", "{seen}");
        }
        assert!(seen[format!("{rpc} with_token")].is_string(), "{seen}");
    }
    assert_eq!(seen["embedder/health"], "SERVING");
    assert_eq!(seen["learner/health"], "SERVING");

    // an actor without the token gives up with the reason, instead of retrying for ever
    let learner_url = format!("http://127.0.0.1:{learner_port}");
    let mut actor = Command::new(env!("CARGO_BIN_EXE_jsae"));
    actor
        .current_dir(&dir)
        .args([
            "actor",
            "--learner",
            &learner_url,
            "--embedder",
            &embedder_url,
        ])
        .args(run)
        .args(["--id", "0", "--envs", "4"]);
    let out = common::stderr_within(&mut actor, 60, "an actor without the token still runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("refused this process's credentials") && err.contains("Unauthenticated"),
        "{err}"
    );
}

#[test]
fn bad_security_flags_stop_a_service_at_start() {
    let dir = fresh_dir("flags");
    std::fs::write(dir.join("short"), "tiny\n").expect("token");
    let learner = [
        "learner",
        "--listen",
        "127.0.0.1:0",
        "--env",
        "gridworld",
        "--algo",
        "ppo",
        "--seed",
        "1",
        "--out",
        "run",
    ];
    let short = jsae(
        &dir,
        &[&learner[..], &["--auth-token-file", "short"]].concat(),
    );
    assert_eq!(short.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&short.stderr).contains("at least 16"));
    let missing = jsae(&dir, &[&learner[..], &["--tls-ca", "absent.pem"]].concat());
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("absent.pem"));
    let pki = TestPki::generate(&dir, "flags").expect("a throw-away CA");
    let actor = jsae(
        &dir,
        &[
            "actor",
            "--learner",
            "http://127.0.0.1:1",
            "--env",
            "gridworld",
            "--algo",
            "ppo",
            "--seed",
            "1",
            "--tls-ca",
            arg(&pki.ca),
        ],
    );
    assert_eq!(actor.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&actor.stderr).contains("https://"));
}

/// A certificate that does not name 127.0.0.1: `jsae train` (separate processes) ends
/// non-zero and says why on its own output, instead of printing nothing while its actors
/// retry for ever.
#[test]
fn a_certificate_for_another_name_ends_the_run_with_the_reason() {
    let dir = fresh_dir("tls-name");
    let pki = TestPki::generate_for(&dir, "elsewhere", &["elsewhere.invalid"]).expect("a CA");
    let mut train = Command::new(env!("CARGO_BIN_EXE_jsae"));
    train.current_dir(&dir).args([
        "train",
        "--env",
        "gridworld",
        "--algo",
        "ppo",
        "--env-steps",
        "4096",
        "--quiet",
        "--out",
        "run",
        "--tls-cert",
        arg(&pki.cert),
        "--tls-key",
        arg(&pki.key),
        "--tls-ca",
        arg(&pki.ca),
    ]);
    let out = common::stderr_within(&mut train, 120, "jsae train with a misnamed certificate");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("actor-0") && (err.contains("certificate") || err.contains("credentials")),
        "{err}"
    );
}
