//! What arrives on the wire cannot hurt a service, over real loopback gRPC:
//! - bytes that are no message get INVALID_ARGUMENT (not INTERNAL) on every RPC (F9);
//! - a bounded fuzz run: at least 100,000 messages of random bytes and mutated valid messages
//!   (flipped, cut, extended, doubled) on every RPC of the embedder, the learner and the
//!   Recommender from 8 concurrent clients, with client streams cut short and server streams
//!   dropped after their first message. No call hangs, no service stops, health answers
//!   SERVING throughout, and well-formed calls are answered afterwards.

use std::time::{Duration, Instant};

use jsae_net::security::Security;
use jsae_settings::{Algo, EnvName, SessionSource};
use jsae_tests::raw_grpc::{RawClient, Shape, call};
use jsae_tests::services::{
    bind, config, fragment, start_embedder, start_learner, stop_signal, transitions,
};
use jsae_wire::pb;
use jsae_wire::{EpisodeStat, EvalReport};
use prost::Message;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tonic::Code;

/// Messages the fuzz run sends, at least.
const MESSAGES: usize = 100_000;
/// Concurrent clients.
const CLIENTS: usize = 8;
/// The fuzz run's seed (printed, so a failure can be replayed).
const SEED: u64 = 20_261_126;

/// One RPC of the three services: where it is, how it is called, and a valid message.
struct Rpc {
    service: usize,
    path: &'static str,
    shape: Shape,
    valid: Vec<u8>,
}

fn rpcs() -> Vec<Rpc> {
    let eval = EvalReport {
        policy_version: 0,
        embedding_version: 0,
        episodes: vec![EpisodeStat {
            ret: 1.0,
            length: 3,
            success: Some(true),
        }],
        stochastic: vec![],
    };
    let session = pb::Session {
        session_id: "fuzz".into(),
        purchases: vec![pb::Purchase {
            item_id: "item-1".into(),
            price: 2.5,
            time_unix_ms: 1,
        }],
    };
    let watch = pb::WatchRequest {
        actor_id: 3,
        evaluates: true,
        rollout_steps: 64,
        envs: 4,
    }
    .encode_to_vec();
    let rpc = |service, path, shape, valid| Rpc {
        service,
        path,
        shape,
        valid,
    };
    vec![
        rpc(
            0,
            "/jsae.v1.Embedder/PushTransitions",
            Shape::ClientStream,
            pb::TransitionBatch::from(transitions(16, 0.5)).encode_to_vec(),
        ),
        rpc(
            0,
            "/jsae.v1.Embedder/WatchEmbedding",
            Shape::ServerStream,
            watch.clone(),
        ),
        rpc(
            0,
            "/jsae.v1.Embedder/HoldEmbedding",
            Shape::Unary,
            pb::HoldRequest {}.encode_to_vec(),
        ),
        rpc(
            1,
            "/jsae.v1.Learner/PushFragments",
            Shape::ClientStream,
            pb::RolloutFragment::from(fragment(2, 8)).encode_to_vec(),
        ),
        rpc(
            1,
            "/jsae.v1.Learner/WatchPolicy",
            Shape::ServerStream,
            watch,
        ),
        rpc(
            1,
            "/jsae.v1.Learner/ReportEval",
            Shape::Unary,
            eval.to_wire(0, 7).encode_to_vec(),
        ),
        rpc(
            2,
            "/jsae.v1.Recommender/Recommend",
            Shape::Unary,
            pb::RecommendRequest {
                history: vec!["item-1".into(), "item-2".into()],
                k: 3,
            }
            .encode_to_vec(),
        ),
        rpc(
            2,
            "/jsae.v1.Recommender/SubmitSessions",
            Shape::ClientStream,
            session.encode_to_vec(),
        ),
    ]
}

/// A message for the fuzz run: random bytes, or `valid` flipped, cut, extended or doubled
/// (and now and then `valid` itself).
fn mutate(valid: &[u8], rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut m = valid.to_vec();
    match rng.random_range(0..7) {
        0 => (0..rng.random_range(0..64)).map(|_| rng.random()).collect(),
        1 => {
            for _ in 0..rng.random_range(1..5) {
                if !m.is_empty() {
                    let i = rng.random_range(0..m.len());
                    m[i] ^= 1 << rng.random_range(0..8);
                }
            }
            m
        }
        2 => {
            m.truncate(rng.random_range(0..=m.len()));
            m
        }
        3 => {
            m.extend((0..rng.random_range(1..16)).map(|_| rng.random::<u8>()));
            m
        }
        4 => [valid, valid].concat(),
        5 => {
            // an over-long varint where a field starts
            let i = rng.random_range(0..=m.len());
            m.splice(i..i, [0xffu8; 11]);
            m
        }
        _ => m,
    }
}

/// `CLIENTS` clients, each seeded, send `MESSAGES` mutated messages in all to random RPCs;
/// no answer may be an internal error or take more than 10 s. The messages sent, the calls
/// made and how often each code answered.
async fn fuzz(
    rpcs: &std::sync::Arc<Vec<Rpc>>,
    channels: &[jsae_net::security::Connection],
) -> (usize, usize, std::collections::BTreeMap<String, usize>) {
    let mut tasks = tokio::task::JoinSet::new();
    for t in 0..CLIENTS {
        let rpcs = rpcs.clone();
        let channels = channels.to_vec();
        tasks.spawn(async move {
            let mut rng = ChaCha8Rng::seed_from_u64(SEED + t as u64);
            let mut clients: Vec<_> = channels.into_iter().map(RawClient::new).collect();
            let (mut sent, mut calls) = (0, 0);
            let mut codes = std::collections::BTreeMap::<String, usize>::new();
            while sent < MESSAGES / CLIENTS {
                let rpc = &rpcs[rng.random_range(0..rpcs.len())];
                let n = match rpc.shape {
                    Shape::ClientStream => rng.random_range(1..=16),
                    _ => 1,
                };
                let messages = (0..n).map(|_| mutate(&rpc.valid, &mut rng)).collect();
                let code = call(
                    &mut clients[rpc.service],
                    rpc.path,
                    rpc.shape,
                    messages,
                    Duration::from_secs(10),
                )
                .await
                .unwrap_or_else(|_| panic!("{} hung", rpc.path));
                assert!(
                    !matches!(code, Code::Internal | Code::Unknown | Code::Unavailable),
                    "{}: {code:?}",
                    rpc.path
                );
                *codes.entry(format!("{code:?}")).or_default() += 1;
                sent += n;
                calls += 1;
            }
            (sent, calls, codes)
        });
    }
    let (mut sent, mut calls) = (0, 0);
    let mut codes = std::collections::BTreeMap::<String, usize>::new();
    while let Some(done) = tasks.join_next().await {
        let (s, c, k) = done.expect("a fuzz client");
        sent += s;
        calls += c;
        for (code, n) in k {
            *codes.entry(code).or_default() += n;
        }
    }
    (sent, calls, codes)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn undecodable_bytes_get_invalid_argument_and_a_fuzz_run_harms_no_service() {
    let mut c = config(EnvName::Gridworld, Algo::Ppo, "wire-fuzz");
    c.env_steps = u64::MAX / 4;
    let embedder_config = config(EnvName::Gridworld, Algo::Jsae, "wire-fuzz-embedder");
    let embedder = start_embedder(&embedder_config).await;
    let learner = start_learner(&c, None).await;

    let mut rc = config(EnvName::Recommender, Algo::Ppo, "wire-fuzz-recommender");
    let r = &mut rc.environment.recommender;
    r.source = SessionSource::Synthetic;
    r.synthetic.items = 40;
    r.synthetic.sessions = 500;
    let rec = std::sync::Arc::new(
        jsae_recommender::Recommender::new(
            &rc,
            jsae_recommender::baseline::PolicyChoice::Popular,
            jsae_nn::DeviceKind::Flex,
        )
        .expect("recommender"),
    );
    let (listener, rec_url) = bind().await;
    let (stop_rec, signal) = stop_signal();
    let recommender = tokio::spawn(jsae_recommender::serve(
        rec,
        listener,
        Default::default(),
        Default::default(),
        Security::default(),
        signal,
    ));
    let urls = [embedder.url.clone(), learner.url.clone(), rec_url];
    let channels: Vec<_> = urls
        .iter()
        .map(|u| Security::default().channel(u).expect("channel"))
        .collect();
    let rpcs = std::sync::Arc::new(rpcs());

    // F9: bytes that are no message at all
    for rpc in rpcs.iter() {
        let mut client = RawClient::new(channels[rpc.service].clone());
        let code = call(
            &mut client,
            rpc.path,
            rpc.shape,
            vec![vec![0xff; 12]],
            Duration::from_secs(10),
        )
        .await
        .expect("an answer in time");
        assert_eq!(code, Code::InvalidArgument, "{}", rpc.path);
    }

    println!("fuzz seed {SEED}");
    let started = Instant::now();
    let (sent, calls, codes) = fuzz(&rpcs, &channels).await;
    let seconds = started.elapsed().as_secs_f64();
    println!("fuzz: {sent} messages in {calls} calls in {seconds:.1} s; answers {codes:?}");
    assert!(sent >= MESSAGES, "{sent} messages");
    assert!(seconds < 180.0, "the fuzz run took {seconds:.0} s");

    // every service is up, healthy, and answers well-formed calls
    assert!(!embedder.handle.is_finished() && !learner.handle.is_finished());
    assert!(!recommender.is_finished());
    for channel in &channels {
        let health = tonic_health::pb::health_client::HealthClient::new(channel.clone())
            .check(tonic_health::pb::HealthCheckRequest::default())
            .await
            .expect("health answers")
            .into_inner();
        assert_eq!(health.status, 1, "SERVING");
    }
    for rpc in rpcs.iter().filter(|r| r.path.ends_with("Recommend")) {
        let mut client = RawClient::new(channels[rpc.service].clone());
        let code = call(
            &mut client,
            rpc.path,
            rpc.shape,
            vec![rpc.valid.clone()],
            Duration::from_secs(10),
        )
        .await
        .expect("in time");
        assert_eq!(code, Code::Ok);
    }
    let _ = stop_rec.send(());
    let _ = recommender.await;
    learner.stop().await.expect("the learner stops cleanly");
    embedder.stop().await.expect("the embedder stops cleanly");
}
