//! The services over real gRPC on 127.0.0.1: actors, learner and embedder started from their
//! libraries on free ports, talking exactly as the processes do (the harness is
//! `jsae_tests::services`).

use std::time::Duration;

use jsae_actor::service::ActorExit;
use jsae_embedder::service::EmbedderOptions;
use jsae_run_dir::MetricsTable;
use jsae_run_dir::{RunDir, Weights};
use jsae_settings::{Algo, EnvName};
use jsae_tests::services::*;
use jsae_wire::ActionBatch;
use jsae_wire::pb;
use tokio::net::TcpListener;
use tonic::Code;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_actors_feed_one_learner_and_policy_versions_reach_them() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "two-actors");
    c.actors = 2;
    c.env_steps = 8_192;
    let learner = start_learner(&c, None).await;
    let a = start_actor(&c, 1, None, &learner.url);
    let b = start_actor(&c, 2, None, &learner.url);
    let (ra, rb) = (
        a.join().await.expect("actor 1"),
        b.join().await.expect("actor 2"),
    );
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    for r in [&ra, &rb] {
        assert_eq!(r.exit, ActorExit::Finished);
        assert!(r.fragments > 0, "{r:?}");
        assert!(increasing(&r.policy_versions), "{:?}", r.policy_versions);
        assert!(r.policy_versions.len() >= 3, "{:?}", r.policy_versions);
    }
    assert!(summary.env_steps >= c.env_steps, "{summary:?}");
    assert!(
        summary.env_steps <= ra.env_steps + rb.env_steps,
        "{summary:?}"
    );
    assert!(
        summary.env_steps > ra.env_steps.max(rb.env_steps),
        "both counted"
    );
    assert!(summary.learner_updates >= 2);
    assert!(RunDir::new(&c.out).summary_json().exists());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn embedding_versions_reach_the_actors_and_the_learner() {
    // JSAE and both baselines, discrete actions; RA also on continuous actions (its f is a
    // decoder MLP), where the policy acts on raw states.
    for (env, algo) in [
        (EnvName::GridworldDiscrete, Algo::Jsae),
        (EnvName::GridworldDiscrete, Algo::Ae),
        (EnvName::GridworldDiscrete, Algo::Ra),
        (EnvName::HalfCheetah, Algo::Ra),
    ] {
        embedding_run_as_services(env, algo).await;
    }
}

async fn embedding_run_as_services(env: EnvName, algo: Algo) {
    let name = format!("{}-{}-services", env.as_str(), algo.as_str());
    let mut c = config(env, algo, &name);
    c.env_steps = 8_192;
    let embedder = start_embedder(&c).await;
    let learner = start_learner(&c, Some(embedder.url.clone())).await;
    let actor = start_actor(&c, 1, Some(&embedder.url), &learner.url);
    let report = actor.join().await.expect("actor");
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    embedder.stop().await.expect("embedder stops cleanly");
    assert_eq!(report.exit, ActorExit::Finished, "{name}");
    assert!(increasing(&report.embedding_versions), "{name}: {report:?}");
    // JSAE's run is checked for a hot swap (a second version reaching the actor); the
    // baselines', for running as services at all (under load their second version can come
    // after the actor's last step).
    let least = if algo == Algo::Jsae { 2 } else { 1 };
    assert!(
        report.embedding_versions.len() >= least,
        "{name}: {report:?}"
    );
    assert!(summary.embedding_version >= 1, "{name}: {summary:?}");
    assert!(summary.eval_return_mean.is_finite(), "{name}: {summary:?}");
    // the evaluation ran on the embedding the final policy was trained on, also when the
    // embedder published a newer one after the learner's last update
    let metrics = MetricsTable::read(&RunDir::new(&c.out).metrics_csv()).expect("metrics.csv");
    let trained_on = metrics
        .column("embedding_version")
        .last()
        .copied()
        .flatten();
    assert_eq!(
        trained_on,
        Some(summary.embedding_version as f64),
        "{name}: {summary:?}"
    );
    let ckpt = RunDir::new(&c.out).checkpoints().path().to_path_buf();
    assert!(
        std::fs::read_dir(&ckpt)
            .expect("checkpoints")
            .filter_map(Result::ok)
            .any(|e| e.file_name().to_string_lossy().starts_with("embedding-v")),
        "{name}: the learner saved the embedding it followed"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_actor_does_not_stop_the_run_and_a_new_one_joins() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "kill-actor");
    c.actors = 2;
    c.env_steps = 12_288;
    let learner = start_learner(&c, None).await;
    let a = start_actor(&c, 1, None, &learner.url);
    let b = start_actor(&c, 2, None, &learner.url);
    wait_for_rows(&c.out, 2).await;
    a.handle.abort(); // gone mid-run, connections dropped
    let joined = start_actor(&c, 3, None, &learner.url);
    let rb = b.join().await.expect("actor 2");
    let rc = joined.join().await.expect("actor 3");
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    assert_eq!(
        (rb.exit, rc.exit),
        (ActorExit::Finished, ActorExit::Finished)
    );
    assert!(rc.fragments > 0, "the new actor contributed: {rc:?}");
    assert!(summary.env_steps >= c.env_steps);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dead_actor_does_not_stall_the_survivor_and_nothing_is_dropped_for_lag() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "dead-actor");
    c.actors = 2;
    c.env_steps = 3_072; // 12 rounds of 2 x 128 steps
    let learner = start_learner(&c, None).await;
    let a = start_actor(&c, 1, None, &learner.url);
    let b = start_actor(&c, 2, None, &learner.url);
    wait_for_rows(&c.out, 2).await;
    a.handle.abort(); // gone for good: every later round waits on it, then goes on without it
    let rb = b.join().await.expect("actor 2");
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    assert_eq!(rb.exit, ActorExit::Finished);
    assert!(summary.env_steps >= c.env_steps, "{summary:?}");
    assert_eq!(summary.dropped_lag, 0, "{summary:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_learner_is_rejoined_by_the_running_actor() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "restart-learner");
    c.env_steps = 12_288;
    let (listener, url) = bind().await;
    let addr = listener.local_addr().expect("addr");
    let first = start_learner_on(&c, listener, url.clone(), None).await;
    let actor = start_actor(&c, 1, None, &url);
    wait_for_rows(&c.out, 2).await;
    assert!(
        first.stop().await.expect("stops cleanly").is_none(),
        "interrupted, no summary"
    );
    let saved = jsae_learner::service::latest_checkpoint(&RunDir::new(&c.out))
        .expect("a checkpoint")
        .version;
    tokio::time::sleep(Duration::from_millis(700)).await; // the actor is retrying meanwhile
    let listener = TcpListener::bind(addr).await.expect("rebind the same port");
    let second = start_learner_on(&c, listener, url, None).await;
    let report = actor.join().await.expect("actor");
    let summary = second
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    assert_eq!(report.exit, ActorExit::Finished);
    assert!(
        increasing(&report.policy_versions),
        "{:?}",
        report.policy_versions
    );
    assert!(
        report.policy_versions.last().is_some_and(|&v| v > saved),
        "versions from the restarted learner reached the actor: {:?} (saved {saved})",
        report.policy_versions
    );
    assert!(summary.policy_version > saved);
    assert!(summary.learner_updates > saved, "{summary:?}");
    // metrics.csv goes on numbering the updates across the restart
    let metrics = MetricsTable::read(&RunDir::new(&c.out).metrics_csv()).expect("metrics.csv");
    let updates: Vec<u64> = metrics
        .column("update")
        .into_iter()
        .map(|u| u.expect("an update number") as u64)
        .collect();
    assert!(increasing(&updates), "{updates:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_messages_get_invalid_argument_and_accepted_ones_are_kept() {
    let c = config(EnvName::Gridworld, Algo::Ppo, "malformed");
    let learner = start_learner(&c, None).await;
    let good = pb::RolloutFragment::from(fragment(2, 8));
    assert_eq!(
        push_fragments(&learner.url, vec![good.clone()])
            .await
            .expect("a good fragment"),
        1
    );
    let mut short = good.clone();
    short.x.pop();
    assert_refused(
        push_fragments(&learner.url, vec![good.clone(), short]).await,
        Code::InvalidArgument,
        "fragment 1: x",
    );
    let mut nan = good.clone();
    nan.rewards[3] = f32::NAN;
    assert_refused(
        push_fragments(&learner.url, vec![nan]).await,
        Code::InvalidArgument,
        "not finite",
    );
    let mut inf = good.clone();
    inf.x[0] = f32::INFINITY;
    assert_refused(
        push_fragments(&learner.url, vec![inf]).await,
        Code::InvalidArgument,
        "not finite",
    );
    let mut future = good.clone();
    future.policy_version = 99;
    assert_refused(
        push_fragments(&learner.url, vec![future]).await,
        Code::InvalidArgument,
        "unknown policy version",
    );
    let mut out_of_range = good.clone();
    out_of_range.actions = Some(ActionBatch::Discrete(vec![512; 8]).into());
    assert_refused(
        push_fragments(&learner.url, vec![out_of_range]).await,
        Code::InvalidArgument,
        "out of range",
    );
    let mut missing = good.clone();
    missing.actions = None;
    assert_refused(
        push_fragments(&learner.url, vec![missing]).await,
        Code::InvalidArgument,
        "missing",
    );
    let huge = pb::RolloutFragment::from(fragment(2, 3_000_000));
    let r = push_fragments(&learner.url, vec![huge]).await;
    assert!(
        matches!(&r, Err(s) if s.code() == Code::ResourceExhausted),
        "oversize: {r:?}"
    );
    // still serving after all that
    assert_eq!(
        push_fragments(&learner.url, vec![good])
            .await
            .expect("still serving"),
        1
    );
    assert!(learner.stop().await.is_ok());

    // the embedder keeps what it accepted before a bad batch: those alone complete the
    // pre-training set and yield a snapshot
    let mut c = config(EnvName::Gridworld, Algo::Jsae, "malformed-embedder");
    c.embedding.pretrain_transitions = 512;
    c.embedding.pretrain_per_action = 0;
    c.embedding.pretrain_epochs = 1;
    let embedder = start_embedder(&c).await;
    let mut client = pb::embedder_client::EmbedderClient::connect(embedder.url.clone())
        .await
        .expect("connect");
    let batches = vec![
        pb::TransitionBatch::from(transitions(256, -0.01)),
        pb::TransitionBatch::from(transitions(256, -0.01)),
        pb::TransitionBatch::from(transitions(4, f32::NAN)),
    ];
    let r = client
        .push_transitions(tokio_stream::iter(batches))
        .await
        .map(|r| r.into_inner().accepted);
    assert_refused(r, Code::InvalidArgument, "transition batch 2: rewards");
    let mut watch = client
        .watch_embedding(pb::WatchRequest::default())
        .await
        .expect("watch")
        .into_inner();
    let first = tokio::time::timeout(Duration::from_secs(60), watch.message())
        .await
        .expect("a snapshot in time")
        .expect("stream")
        .expect("a chunk");
    assert_eq!(first.version, 1);
    embedder.stop().await.expect("stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_answers_serving_and_reflection_lists_the_services() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    let c = config(EnvName::Gridworld, Algo::Jsae, "health");
    let embedder = start_embedder(&c).await;
    let learner = start_learner(&c, Some(embedder.url.clone())).await;
    for (url, service) in [
        (&embedder.url, "jsae.v1.Embedder"),
        (&learner.url, "jsae.v1.Learner"),
        (&learner.url, ""),
    ] {
        let mut health = HealthClient::new(channel(url).await);
        let status = health
            .check(HealthCheckRequest {
                service: service.into(),
            })
            .await
            .expect("health check")
            .into_inner()
            .status;
        assert_eq!(
            status,
            ServingStatus::Serving as i32,
            "{service:?} at {url}"
        );
    }
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    let mut reflection = ServerReflectionClient::new(channel(&learner.url).await);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut answers = reflection
        .server_reflection_info(tokio_stream::iter(vec![request]))
        .await
        .expect("reflection")
        .into_inner();
    let answer = answers.message().await.expect("stream").expect("an answer");
    let Some(MessageResponse::ListServicesResponse(list)) = answer.message_response else {
        panic!("not a service list: {answer:?}");
    };
    let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
    for want in [
        "jsae.v1.Learner",
        "jsae.v1.Embedder",
        "grpc.health.v1.Health",
    ] {
        assert!(
            names.iter().any(|n| n == want),
            "{want} missing from {names:?}"
        );
    }
    learner.stop().await.expect("learner stops");
    embedder.stop().await.expect("embedder stops");
}

/// A JSAE gridworld run whose embedder pre-trains on the 512 transitions of
/// `pretrain_to_version_one`, in one pass.
fn pretrained_on_512(name: &str) -> jsae_settings::TrainConfig {
    let mut c = config(EnvName::Gridworld, Algo::Jsae, name);
    c.embedding.pretrain_transitions = 512;
    c.embedding.pretrain_per_action = 0;
    c.embedding.pretrain_epochs = 1;
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_embedder_continues_its_version_line() {
    let c = pretrained_on_512("restart-embedder");
    let options = EmbedderOptions {
        checkpoint_dir: Some(RunDir::new(&c.out).checkpoints().path().to_path_buf()),
        pretrain_from: None,
        metrics: Default::default(),
        security: Default::default(),
        logged: None,
    };
    let first = start_embedder_with(&c, options.clone()).await;
    pretrain_to_version_one(&first.url).await;
    first.stop().await.expect("stops cleanly");
    // no new transitions: the restarted embedder serves the saved version at once
    let second = start_embedder_with(&c, options).await;
    assert_eq!(first_embedding_version(&second.url).await, 1);
    second.stop().await.expect("stops cleanly");
}

/// `Embedder.HoldEmbedding` (the learner asks from `embedding.hold_from` of the run on): the
/// updates run before it, and none after it, whatever arrives (stopping drains the queue).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_held_embedder_publishes_no_new_version() {
    let mut c = pretrained_on_512("held-embedder");
    c.embedding.update_every = 512;
    c.embedding.update_steps = 1;
    let checkpoints = RunDir::new(&c.out).checkpoints();
    let options = EmbedderOptions {
        checkpoint_dir: Some(checkpoints.path().to_path_buf()),
        ..Default::default()
    };
    let embedder = start_embedder_with(&c, options).await;
    pretrain_to_version_one(&embedder.url).await;
    let mut client = pb::embedder_client::EmbedderClient::connect(embedder.url.clone())
        .await
        .expect("connect");
    let batches = |n| vec![pb::TransitionBatch::from(transitions(512, -0.01)); n];
    client
        .push_transitions(tokio_stream::iter(batches(1)))
        .await
        .expect("accepted");
    let newest = || checkpoints.read_latest(Weights::Embedding).map(|(v, _)| v);
    tokio::time::timeout(Duration::from_secs(60), async {
        while newest() != Some(2) {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("an update before the hold");
    client
        .hold_embedding(pb::HoldRequest {})
        .await
        .expect("held");
    client
        .push_transitions(tokio_stream::iter(batches(4)))
        .await
        .expect("accepted");
    embedder.stop().await.expect("stops cleanly");
    assert_eq!(newest(), Some(2), "no update after the hold");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_recommender_follows_a_live_run_and_swaps_in_new_versions() {
    use jsae_recommender::{Recommender, WeightSources};
    use jsae_settings::SessionSource;
    let mut c = config(EnvName::Recommender, Algo::Jsae, "recommender-live");
    c.env_steps = 12_288;
    let r = &mut c.environment.recommender;
    r.source = SessionSource::Synthetic;
    r.top_n = 50;
    r.synthetic.items = 40;
    r.synthetic.sessions = 1_000;
    let embedder = start_embedder(&c).await;
    let learner = start_learner(&c, Some(embedder.url.clone())).await;
    let rec = std::sync::Arc::new(
        Recommender::new(
            &c,
            jsae_recommender::baseline::PolicyChoice::Learned,
            jsae_nn::DeviceKind::Flex,
        )
        .expect("recommender"),
    );
    let (listener, rec_url) = bind().await;
    let (stop_rec, signal) = stop_signal();
    let sources = WeightSources {
        learner: Some(learner.url.clone()),
        embedder: Some(embedder.url.clone()),
        run: None,
    };
    let served = tokio::spawn(jsae_recommender::serve(
        rec,
        listener,
        sources,
        Default::default(),
        Default::default(),
        signal,
    ));
    let mut client = pb::recommender_client::RecommenderClient::new(channel(&rec_url).await);
    let ask = pb::RecommendRequest {
        history: vec!["item-0".into(), "item-1".into()],
        k: 5,
    };
    let before = client
        .recommend(ask.clone())
        .await
        .expect_err("no policy yet");
    assert_eq!(before.code(), Code::Unavailable, "{before:?}");

    let actor = start_actor(&c, 1, Some(&embedder.url), &learner.url);
    let mut policy_versions = Vec::new();
    let mut embedding_versions = Vec::new();
    while !actor.handle.is_finished() {
        if let Ok(r) = client.recommend(ask.clone()).await {
            let r = r.into_inner();
            assert_eq!(r.items.len(), 5);
            if policy_versions.last() != Some(&r.policy_version) {
                policy_versions.push(r.policy_version);
            }
            if embedding_versions.last() != Some(&r.embedding_version) {
                embedding_versions.push(r.embedding_version);
            }
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    actor.join().await.expect("actor");
    learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    embedder.stop().await.expect("embedder stops");
    let _ = stop_rec.send(());
    served
        .await
        .expect("task")
        .expect("recommender stops cleanly");
    assert!(policy_versions.len() >= 3, "{policy_versions:?}");
    assert!(increasing(&policy_versions), "{policy_versions:?}");
    assert!(embedding_versions.len() >= 2, "{embedding_versions:?}");
    assert!(increasing(&embedding_versions), "{embedding_versions:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fresh_learner_learns_from_logged_purchases_before_its_first_snapshot() {
    use jsae_settings::SessionSource;
    // the policy's outputs on a few inputs: the weights, whatever ids the record gives them
    // and whether a count prior came with them
    let outputs = |c: &jsae_settings::TrainConfig, bytes: Option<Vec<u8>>| {
        let mut l = jsae_learner::Learner::for_run(c);
        if let Some(bytes) = bytes {
            l.restore(&jsae_wire::PolicySnapshot { version: 0, bytes })
                .expect("the checkpoint loads");
        }
        let d = l.policy().input_dim();
        let x: Vec<f32> = (0..4 * d).map(|i| ((i * 7) % 5) as f32 / 4.0).collect();
        (l.policy().head_outputs(&x, l.prior()), l.prior().is_some())
    };
    let first_snapshot = |pretrain: usize, prior: bool, name: &str| {
        let mut c = config(EnvName::Recommender, Algo::Ppo, name);
        let r = &mut c.environment.recommender;
        r.source = SessionSource::Synthetic;
        r.top_n = 50;
        r.synthetic.items = 40;
        r.synthetic.sessions = 500;
        c.ppo.recommender.logged_pretrain_epochs = pretrain;
        c.ppo.recommender.logged_prior = prior;
        async move {
            let fresh = outputs(&c, None);
            let learner = start_learner(&c, None).await;
            let out = RunDir::new(&c.out);
            let mut first = None;
            for _ in 0..600 {
                first = jsae_learner::service::latest_checkpoint(&out);
                if first.is_some() {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            learner.stop().await.expect("stops cleanly");
            let first = first.expect("the first snapshot was written");
            assert_eq!(first.version, 0);
            (fresh, outputs(&c, Some(first.bytes)))
        }
    };
    let (fresh, served) = first_snapshot(0, false, "logged-off").await;
    assert_eq!(fresh, served, "without pre-training: the fresh weights");
    let (fresh, served) = first_snapshot(2, false, "logged-on").await;
    assert_ne!(fresh.0, served.0, "pre-trained before the first snapshot");
    assert!(!served.1);
    let (fresh, served) = first_snapshot(0, true, "logged-prior").await;
    assert!(
        !fresh.1 && served.1,
        "the counted prior travels with the first snapshot"
    );
    assert_ne!(fresh.0, served.0);
}
