//! `jsae bench --transport`: how fast the services take in data over loopback gRPC, next to
//! the same components fed through an in-process channel, in one run.
//!
//! - Embedder ingest: random gridworld-discrete transition batches (2,048 transitions, as
//!   an actor with 16 environments and 128-step rollouts sends them) into the embedder's
//!   replay buffer, with training held off so only the transport and the ingest are timed.
//! - Learner fragments: JSAE-shaped fragments (128 steps, x 8-d, e 2-d) into the learner,
//!   with a batch size it never reaches, so only validation, transport and buffering count.

use std::time::Instant;

use jsae_embedder::EmbedderTrainer;
use jsae_embedder::service::EmbedderOptions;
use jsae_learner::Learner;
use jsae_learner::service::LearnerOptions;
use jsae_settings::TrainConfig;
use jsae_wire::pb;
use jsae_wire::{ActionBatch, RolloutFragment, TransitionBatch};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use jsae_actor::worker::ActorWorker;

/// One measured rate, over gRPC and in-process.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TransportRate {
    /// Items per second over loopback gRPC.
    pub grpc: f64,
    /// Items per second through an in-process channel.
    pub in_process: f64,
}

fn transition_batches(config: &TrainConfig, n: usize) -> Vec<TransitionBatch> {
    let mut worker =
        ActorWorker::new(config, 0, config.device).expect("benchmark environments need no data");
    (0..n)
        .map(|_| worker.collect(config.rollout_len).transitions)
        .collect()
}

fn fragments(n: usize, steps: usize) -> Vec<RolloutFragment> {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    (0..n)
        .map(|i| RolloutFragment {
            actor_id: 1,
            env_index: (i % 16) as u32,
            policy_version: 0,
            embedding_version: 0,
            actor_env_steps: (i * steps) as u64,
            x_dim: 8,
            x: (0..steps * 8)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect(),
            actions: ActionBatch::Continuous {
                dim: 2,
                data: (0..steps * 2)
                    .map(|_| rng.random_range(-1.0..1.0))
                    .collect(),
            },
            logp: vec![-1.5; steps],
            rewards: vec![-0.01; steps],
            terminated: vec![false; steps],
            truncated: vec![false; steps],
            truncated_next_x: vec![],
            last_next_x: vec![0.0; 8],
            episodes: vec![],
            actor_incarnation: 1,
            visit_keys: Vec::new(),
        })
        .collect()
}

fn base_config() -> TrainConfig {
    let mut c = super::gridworld_as_measured();
    c.env_steps = u64::MAX / 2;
    c.out = std::env::temp_dir().join(format!("jsae-bench-transport-{}", std::process::id()));
    c
}

async fn embedder_grpc(config: &TrainConfig, batches: &[TransitionBatch]) -> anyhow::Result<f64> {
    let listener = jsae_net::bind("127.0.0.1:0").await?;
    let url = format!("http://{}", listener.local_addr()?);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(jsae_embedder::service::serve(
        config.clone(),
        listener,
        EmbedderOptions::default(),
        async move {
            let _ = stopped.await;
        },
    ));
    let mut client = pb::embedder_client::EmbedderClient::new(
        jsae_net::security::Security::default().channel(&url)?,
    )
    .max_encoding_message_size(jsae_wire::MAX_MESSAGE_BYTES);
    let wire: Vec<pb::TransitionBatch> = batches.iter().cloned().map(Into::into).collect();
    // warm up the connection
    client
        .push_transitions(tokio_stream::iter(wire[..1].to_vec()))
        .await?;
    let started = Instant::now();
    let accepted = client
        .push_transitions(tokio_stream::iter(wire))
        .await?
        .into_inner()
        .accepted;
    let secs = started.elapsed().as_secs_f64();
    let _ = stop.send(());
    server.await??;
    let n: usize = batches
        .iter()
        .take(accepted as usize)
        .map(TransitionBatch::len)
        .sum();
    Ok(n as f64 / secs)
}

fn embedder_in_process(config: &TrainConfig, batches: &[TransitionBatch]) -> f64 {
    let (states, actions) = config.spaces();
    let (tx, rx) = std::sync::mpsc::sync_channel::<TransitionBatch>(2);
    let embedding = config.embedding.clone();
    let representation = config.algo.representation();
    let (seed, device) = (config.seed, config.device);
    let started = Instant::now();
    let consumer = std::thread::spawn(move || {
        let mut trainer =
            EmbedderTrainer::new(embedding, representation, &states, &actions, seed, device);
        let mut n = 0;
        while let Ok(b) = rx.recv() {
            if trainer.ingest(&b).is_ok() {
                n += b.len();
            }
        }
        n
    });
    for b in batches {
        if tx.send(b.clone()).is_err() {
            break;
        }
    }
    drop(tx);
    let n = consumer.join().unwrap_or(0);
    n as f64 / started.elapsed().as_secs_f64()
}

async fn learner_grpc(config: &TrainConfig, frags: &[RolloutFragment]) -> anyhow::Result<f64> {
    let listener = jsae_net::bind("127.0.0.1:0").await?;
    let url = format!("http://{}", listener.local_addr()?);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let options = LearnerOptions {
        embedder: None,
        logged: None,
        resume: false,
        metrics: Default::default(),
        security: Default::default(),
    };
    let server = tokio::spawn(jsae_learner::service::serve(
        config.clone(),
        listener,
        options,
        async move {
            let _ = stopped.await;
        },
    ));
    let mut client = pb::learner_client::LearnerClient::new(
        jsae_net::security::Security::default().channel(&url)?,
    )
    .max_encoding_message_size(jsae_wire::MAX_MESSAGE_BYTES);
    let wire: Vec<pb::RolloutFragment> = frags.iter().cloned().map(Into::into).collect();
    client
        .push_fragments(tokio_stream::iter(wire[..1].to_vec()))
        .await?;
    let started = Instant::now();
    let accepted = client
        .push_fragments(tokio_stream::iter(wire))
        .await?
        .into_inner()
        .accepted;
    let secs = started.elapsed().as_secs_f64();
    let _ = stop.send(());
    server.await??;
    Ok(accepted as f64 / secs)
}

fn learner_in_process(config: &TrainConfig, frags: &[RolloutFragment]) -> f64 {
    let (tx, rx) = std::sync::mpsc::sync_channel::<RolloutFragment>(256);
    let mut ppo = config.ppo.clone();
    ppo.batch_steps = usize::MAX;
    let (seed, device, steps) = (config.seed, config.device, config.env_steps);
    let started = Instant::now();
    let consumer = std::thread::spawn(move || {
        let mut learner = Learner::new(
            ppo,
            8,
            jsae_agent::PolicyHead::Gaussian { dim: 2 },
            steps,
            seed,
            device,
        );
        let mut n = 0u64;
        while let Ok(f) = rx.recv() {
            if learner.ingest(f).is_ok() {
                n += 1;
            }
        }
        n
    });
    for f in frags {
        if tx.send(f.clone()).is_err() {
            break;
        }
    }
    drop(tx);
    let n = consumer.join().unwrap_or(0);
    n as f64 / started.elapsed().as_secs_f64()
}

/// Measures both rates; `quick` uses fewer messages.
pub fn measure(quick: bool) -> anyhow::Result<(TransportRate, TransportRate)> {
    let n_batches = if quick { 20 } else { 200 };
    let n_fragments = if quick { 200 } else { 4_000 };
    let mut embed_cfg = base_config();
    embed_cfg.embedding.pretrain_transitions = (n_batches + 2) * embed_cfg.round_steps() + 1;
    embed_cfg.embedding.replay_capacity = embed_cfg.embedding.pretrain_transitions;
    embed_cfg.embedding.pretrain_per_action = 0;
    let mut learn_cfg = base_config();
    learn_cfg.actors = 1 << 20; // a batch the learner never completes
    let batches = transition_batches(&embed_cfg, n_batches);
    let frags = fragments(n_fragments, 128);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let embed_grpc = runtime.block_on(embedder_grpc(&embed_cfg, &batches))?;
    let embed_local = embedder_in_process(&embed_cfg, &batches);
    let learn_grpc = runtime.block_on(learner_grpc(&learn_cfg, &frags))?;
    let learn_local = learner_in_process(&learn_cfg, &frags);
    let _ = std::fs::remove_dir_all(&learn_cfg.out);
    Ok((
        TransportRate {
            grpc: embed_grpc,
            in_process: embed_local,
        },
        TransportRate {
            grpc: learn_grpc,
            in_process: learn_local,
        },
    ))
}

/// The report `jsae bench --transport` prints.
pub fn run(quick: bool) -> String {
    match measure(quick) {
        Err(e) => format!("transport benchmark failed: {e:#}\n"),
        Ok((embed, learn)) => {
            let mut out = String::from(
                "transport (loopback gRPC, TCP_NODELAY) vs in-process channel, same components\n",
            );
            out.push_str(&format!(
                "{:<44} {:>12} {:>12} {:>14}\n",
                "measure", "gRPC", "in-process", "gRPC / in-proc"
            ));
            for (name, r) in [
                ("embedder ingest (transitions/s)", embed),
                ("learner fragments (fragments/s, 128 steps)", learn),
            ] {
                out.push_str(&format!(
                    "{:<44} {:>12.0} {:>12.0} {:>14.2}\n",
                    name,
                    r.grpc,
                    r.in_process,
                    r.grpc / r.in_process
                ));
            }
            out
        }
    }
}
