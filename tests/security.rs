//! The token and TLS in front of the training services, over real loopback gRPC:
//! - with a token, every RPC of the embedder and the learner, and reflection, answers
//!   UNAUTHENTICATED without it or with another; health answers SERVING to anyone;
//! - a run whose embedder, learner and actor talk TLS (with the token) trains to the end,
//!   and so does one with mutual TLS, whose learner refuses a client without a certificate.

use std::path::Path;
use std::time::Duration;

use jsae_net::security::test_certs::TestPki;
use jsae_net::security::{Security, SecurityFlags};
use jsae_settings::{Algo, EnvName};
use jsae_tests::services::{
    bind_for, config, start_actor_secured, start_embedder_with, start_learner_secured,
};
use jsae_tests::temp_dir;
use jsae_wire::pb;
use tonic::Code;

const TOKEN: &str = "a4c1e9f07b3d5a2c8e6f1b0d9c7a5e3f";

fn flags(dir: &Path, token: &str, pki: Option<&TestPki>, mutual: bool) -> SecurityFlags {
    std::fs::create_dir_all(dir).expect("dir");
    let file = dir.join(format!("token-{}", token.len()));
    std::fs::write(&file, token).expect("token");
    SecurityFlags {
        auth_token_file: Some(file),
        tls_cert: pki.map(|p| p.cert.clone()),
        tls_key: pki.map(|p| p.key.clone()),
        tls_ca: pki.map(|p| p.ca.clone()),
        tls_client_ca: pki.filter(|_| mutual).map(|p| p.ca.clone()),
    }
}

fn load(flags: &SecurityFlags) -> Security {
    flags.load().expect("security flags")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_a_token_every_rpc_but_health_needs_it() {
    let c = config(EnvName::Gridworld, Algo::Jsae, "security-token");
    let dir = temp_dir("security-token-files");
    let secured = load(&flags(&dir, TOKEN, None, false));
    let embedder = start_embedder_with(
        &c,
        jsae_embedder::service::EmbedderOptions {
            security: secured.clone(),
            ..Default::default()
        },
    )
    .await;
    let (listener, learner_url) = bind_for(&secured).await;
    let learner = start_learner_secured(
        &c,
        listener,
        learner_url.clone(),
        Some(embedder.url.clone()),
        secured.clone(),
    )
    .await;
    let wrong = load(&flags(
        &dir,
        "b4c1e9f07b3d5a2c8e6f1b0d9c7a5e3f0",
        None,
        false,
    ));
    for (who, client) in [("no token", Security::default()), ("wrong token", wrong)] {
        let e = client.channel(&embedder.url).expect("channel");
        let l = client.channel(&learner_url).expect("channel");
        let mut embedder_rpc = pb::embedder_client::EmbedderClient::new(e.clone());
        let mut learner_rpc = pb::learner_client::LearnerClient::new(l.clone());
        let codes = [
            outcome(
                embedder_rpc
                    .push_transitions(tokio_stream::iter(Vec::<pb::TransitionBatch>::new()))
                    .await,
            ),
            outcome(
                embedder_rpc
                    .watch_embedding(pb::WatchRequest::default())
                    .await,
            ),
            outcome(embedder_rpc.hold_embedding(pb::HoldRequest {}).await),
            outcome(
                learner_rpc
                    .push_fragments(tokio_stream::iter(Vec::<pb::RolloutFragment>::new()))
                    .await,
            ),
            outcome(learner_rpc.watch_policy(pb::WatchRequest::default()).await),
            outcome(learner_rpc.report_eval(pb::EvalReport::default()).await),
            reflection(l.clone()).await,
        ];
        for (i, code) in codes.iter().enumerate() {
            assert_eq!(*code, Err(Code::Unauthenticated), "{who}: call {i}");
        }
        for channel in [e, l] {
            let health = tonic_health::pb::health_client::HealthClient::new(channel)
                .check(tonic_health::pb::HealthCheckRequest::default())
                .await
                .expect("health answers without the token")
                .into_inner();
            assert_eq!(health.status, 1, "{who}: SERVING");
        }
    }
    // with the token the same calls get through
    let l = secured.channel(&learner_url).expect("channel");
    assert_eq!(reflection(l.clone()).await, Ok(()));
    let pushed = pb::learner_client::LearnerClient::new(l)
        .push_fragments(tokio_stream::iter(Vec::<pb::RolloutFragment>::new()))
        .await;
    assert_eq!(pushed.map(|r| r.into_inner().accepted).ok(), Some(0));
    learner.stop().await.expect("learner stops");
    embedder.stop().await.expect("embedder stops");
}

/// A call's outcome: `Ok`, or its status code.
fn outcome<T>(answer: Result<T, tonic::Status>) -> Result<(), Code> {
    answer.map(drop).map_err(|s| s.code())
}

/// Lists the services through reflection: `Ok` once an answer came.
async fn reflection(channel: jsae_net::security::Connection) -> Result<(), Code> {
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut answers = ServerReflectionClient::new(channel)
        .server_reflection_info(tokio_stream::iter(vec![request]))
        .await
        .map_err(|s| s.code())?
        .into_inner();
    answers.message().await.map_err(|s| s.code())?;
    Ok(())
}

async fn tls_run(name: &str, mutual: bool) {
    let mut c = config(EnvName::Gridworld, Algo::Jsae, name);
    c.env_steps = 4_096;
    let dir = temp_dir(&format!("{name}-pki"));
    let pki = TestPki::generate(&dir, name).expect("a throw-away CA");
    let secured = load(&flags(&dir, TOKEN, Some(&pki), mutual));
    let embedder = start_embedder_with(
        &c,
        jsae_embedder::service::EmbedderOptions {
            security: secured.clone(),
            ..Default::default()
        },
    )
    .await;
    let embedder_url = embedder.url.clone();
    let (listener, learner_url) = bind_for(&secured).await;
    assert!(learner_url.starts_with("https://"), "{learner_url}");
    let learner = start_learner_secured(
        &c,
        listener,
        learner_url.clone(),
        Some(embedder_url.clone()),
        secured.clone(),
    )
    .await;
    if mutual {
        // a client that trusts the server but shows no certificate is refused
        let anonymous = SecurityFlags {
            tls_ca: Some(pki.ca.clone()),
            ..flags(&dir, TOKEN, None, false)
        };
        let channel = load(&anonymous).channel(&learner_url).expect("channel");
        let refused = tonic_health::pb::health_client::HealthClient::new(channel)
            .check(tonic_health::pb::HealthCheckRequest::default())
            .await;
        assert!(
            refused.is_err(),
            "a client without a certificate was answered"
        );
    }
    let actor = start_actor_secured(&c, 0, Some(&embedder_url), &learner_url, secured.clone());
    let summary = tokio::time::timeout(Duration::from_secs(240), learner.join())
        .await
        .expect("the run ends in time")
        .expect("the learner ends the run")
        .expect("a summary");
    assert!(summary.env_steps >= 4_096, "{summary:?}");
    assert!(summary.embedding_version >= 1, "{summary:?}");
    let _ = actor.stop().await;
    embedder.stop().await.expect("embedder stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tls_run_trains_to_the_end() {
    tls_run("security-tls", false).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mutual_tls_run_trains_to_the_end() {
    tls_run("security-mtls", true).await;
}
