//! What clients may hold open, over real gRPC on 127.0.0.1: policy and embedding streams are
//! capped per connection (and in all), an actor id belongs to the connection whose stream
//! named it, and `Health.Watch` is capped while `Check` always answers. The harness is
//! `jsae_tests::services`.

use std::time::Duration;

use jsae_net::streams::{MAX_HEALTH_WATCHES_PER_CONNECTION, MAX_WATCHES_PER_CONNECTION};
use jsae_settings::{Algo, EnvName};
use jsae_tests::services::*;
use jsae_wire::pb;
use tonic::Code;
use tonic_health::pb::HealthCheckRequest;
use tonic_health::pb::health_client::HealthClient;

fn follower() -> pb::WatchRequest {
    pb::WatchRequest::default()
}

fn actor(actor_id: u64) -> pb::WatchRequest {
    pb::WatchRequest {
        actor_id,
        evaluates: true,
        ..Default::default()
    }
}

async fn watch(
    channel: &tonic::transport::Channel,
    request: pb::WatchRequest,
) -> Result<tonic::Streaming<pb::PolicyEvent>, tonic::Status> {
    pb::learner_client::LearnerClient::new(channel.clone())
        .watch_policy(request)
        .await
        .map(tonic::Response::into_inner)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn policy_streams_are_capped_per_connection_and_an_actor_id_is_its_connections() {
    let c = config(EnvName::Gridworld, Algo::Ppo, "limits-policy");
    let learner = start_learner(&c, None).await;
    let one = channel(&learner.url).await;
    let mut open = Vec::new();
    for _ in 0..MAX_WATCHES_PER_CONNECTION {
        open.push(watch(&one, follower()).await.expect("within the cap"));
    }
    let refused = watch(&one, follower()).await.expect_err("past the cap");
    assert_eq!(refused.code(), Code::ResourceExhausted, "{refused:?}");
    assert!(
        refused.message().contains("MAX_WATCHES_PER_CONNECTION"),
        "{refused:?}"
    );
    // another connection is not held back by this one
    let two = channel(&learner.url).await;
    let mut held = watch(&two, actor(5)).await.expect("another connection");
    let _ = until_snapshot(&mut held, 0).await;
    // actor 5 is two's: a third connection naming it gets neither its place nor its requests
    let three = channel(&learner.url).await;
    let taken = watch(&three, actor(5)).await.expect_err("actor 5 is held");
    assert_eq!(taken.code(), Code::AlreadyExists, "{taken:?}");
    // two's own second stream is fine, and once two's streams close the id is free
    let again = watch(&two, actor(5))
        .await
        .expect("the holder's connection");
    drop((held, again));
    let mut free = None;
    for _ in 0..50 {
        match watch(&three, actor(5)).await {
            Ok(s) => {
                free = Some(s);
                break;
            }
            Err(e) => assert_eq!(e.code(), Code::AlreadyExists, "{e:?}"),
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        free.is_some(),
        "actor 5 free once its holder's streams closed"
    );
    // closing streams frees the connection's places
    open.clear();
    let mut reopened = false;
    for _ in 0..50 {
        if watch(&one, follower()).await.is_ok() {
            reopened = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(reopened, "a place on the first connection again");
    learner.stop().await.expect("learner stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn embedding_streams_are_capped_per_connection() {
    let c = config(EnvName::Gridworld, Algo::Jsae, "limits-embedding");
    let embedder = start_embedder(&c).await;
    let one = channel(&embedder.url).await;
    let watch = || {
        let mut client = pb::embedder_client::EmbedderClient::new(one.clone());
        async move { client.watch_embedding(follower()).await }
    };
    let mut open = Vec::new();
    for _ in 0..MAX_WATCHES_PER_CONNECTION {
        open.push(watch().await.expect("within the cap"));
    }
    let refused = watch().await.expect_err("past the cap");
    assert_eq!(refused.code(), Code::ResourceExhausted, "{refused:?}");
    let other = channel(&embedder.url).await;
    pb::embedder_client::EmbedderClient::new(other)
        .watch_embedding(follower())
        .await
        .expect("another connection");
    embedder.stop().await.expect("embedder stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_watch_is_capped_and_check_always_answers() {
    let c = config(EnvName::Gridworld, Algo::Ppo, "limits-health");
    let learner = start_learner(&c, None).await;
    let one = channel(&learner.url).await;
    let mut health = HealthClient::new(one.clone());
    let mut open = Vec::new();
    for _ in 0..MAX_HEALTH_WATCHES_PER_CONNECTION {
        let mut stream = health
            .watch(HealthCheckRequest::default())
            .await
            .expect("within the cap")
            .into_inner();
        let first = tokio::time::timeout(Duration::from_secs(10), stream.message())
            .await
            .expect("in time")
            .expect("a status")
            .expect("not ended");
        assert_eq!(first.status, 1, "SERVING");
        open.push(stream);
    }
    let refused = health
        .watch(HealthCheckRequest::default())
        .await
        .expect_err("past the cap");
    assert_eq!(refused.code(), Code::ResourceExhausted, "{refused:?}");
    let served = health
        .check(HealthCheckRequest {
            service: "jsae.v1.Learner".into(),
        })
        .await
        .expect("Check answers")
        .into_inner();
    assert_eq!(served.status, 1, "SERVING");
    let unknown = health
        .check(HealthCheckRequest {
            service: "no.such.Service".into(),
        })
        .await
        .expect_err("not served here");
    assert_eq!(unknown.code(), Code::NotFound);
    learner.stop().await.expect("learner stops");
}
