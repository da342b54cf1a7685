//! Finite but absurd values over real gRPC on 127.0.0.1: a behaviour log-probability of
//! -3e38, an input of 3e38, a fragment with no step and many episode statistics, more
//! episodes than a fragment's steps can end, an episode of length 2^32-1. Each is refused at
//! the wire, and the learner trains on what follows with finite losses. The harness is
//! `jsae_tests::services`.

use jsae_run_dir::MetricsTable;
use jsae_run_dir::RunDir;
use jsae_settings::{Algo, EnvName};
use jsae_tests::services::*;
use jsae_wire::pb;
use jsae_wire::{ActionBatch, RolloutFragment};
use tonic::Code;

/// The fragment without its steps (what it says of its episodes kept).
fn empty(f: pb::RolloutFragment) -> pb::RolloutFragment {
    let mut f = RolloutFragment::try_from(f).expect("a valid fragment");
    f.x.clear();
    f.logp.clear();
    f.rewards.clear();
    f.terminated.clear();
    f.truncated.clear();
    f.truncated_next_x.clear();
    f.actions = ActionBatch::Discrete(Vec::new());
    f.into()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn absurd_log_probs_and_inputs_are_refused_and_the_policy_stays_finite() {
    let c = config(EnvName::Gridworld, Algo::Ppo, "bounds-logp");
    let learner = start_learner(&c, None).await;
    let n = c.round_steps() / 2;
    let mut poisoned = claimed_fragment(&c, 1, 7, 64, 64, 0);
    poisoned.logp[17] = -3e38;
    assert_refused(
        push_fragments(&learner.url, vec![poisoned]).await,
        Code::InvalidArgument,
        "logp: value 17 is -300000000000000000000000000000000000000, outside",
    );
    let mut poisoned = claimed_fragment(&c, 1, 7, 64, 64, 0);
    poisoned.x[5] = 3e38;
    assert_refused(
        push_fragments(&learner.url, vec![poisoned]).await,
        Code::InvalidArgument,
        "x: value 5",
    );
    // the genuine stream goes on: two updates, every loss finite
    let genuine = (1..=4).map(|k| claimed_fragment(&c, 1, 9, (k * n) as u64, n, 0));
    push_all(&learner.url, genuine.collect()).await;
    wait_for_rows(&c.out, 2).await;
    let table = MetricsTable::read(&RunDir::new(&c.out).metrics_csv()).expect("metrics.csv");
    for column in ["policy_loss", "value_loss", "grad_norm"] {
        let values = table.column(column);
        assert_eq!(values.len(), 2, "{column}");
        assert!(
            values.iter().all(|v| v.is_some_and(f64::is_finite)),
            "{column}: {values:?}"
        );
    }
    learner.stop().await.expect("learner stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn empty_fragments_and_more_episodes_than_ends_are_refused() {
    let c = config(EnvName::Gridworld, Algo::Ppo, "bounds-empty");
    let learner = start_learner(&c, None).await;
    let stat = pb::EpisodeStat {
        ret: 1.0,
        length: 10,
        success: Some(true),
    };
    let mut zero = empty(claimed_fragment(&c, 1, 7, 8, 8, 0));
    zero.episodes = vec![stat; 10_000];
    assert_refused(
        push_fragments(&learner.url, vec![zero]).await,
        Code::InvalidArgument,
        "rewards: empty (at least one step)",
    );
    let mut many = claimed_fragment(&c, 1, 7, 8, 8, 0);
    let ends = many
        .terminated
        .iter()
        .zip(&many.truncated)
        .filter(|&(&t, &c)| t || c)
        .count();
    many.episodes = vec![stat; ends + 1];
    assert_refused(
        push_fragments(&learner.url, vec![many]).await,
        Code::InvalidArgument,
        "at most one per step that ends one",
    );
    let mut forged = claimed_fragment(&c, 1, 7, 8, 8, 0);
    forged.truncated[7] = true;
    forged.truncated_next_x = forged.last_next_x.clone();
    forged.episodes = vec![pb::EpisodeStat {
        ret: 1.7e308,
        length: u32::MAX,
        success: Some(true),
    }];
    assert_refused(
        push_fragments(&learner.url, vec![forged]).await,
        Code::InvalidArgument,
        "episodes: episode 0",
    );
    learner.stop().await.expect("learner stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_that_never_speak_are_closed_and_the_service_answers_throughout() {
    use tokio::io::AsyncReadExt;
    let c = config(EnvName::Gridworld, Algo::Ppo, "bounds-silent");
    let learner = start_learner(&c, None).await;
    let addr = learner.url.trim_start_matches("http://").to_string();
    let mut silent = Vec::new();
    for _ in 0..300 {
        silent.push(
            tokio::net::TcpStream::connect(&addr)
                .await
                .expect("connects"),
        );
    }
    let health = || async {
        let channel = tonic::transport::Endpoint::from_shared(learner.url.clone())
            .expect("a URL")
            .connect()
            .await
            .expect("connects");
        tonic_health::pb::health_client::HealthClient::new(channel)
            .check(tonic_health::pb::HealthCheckRequest::default())
            .await
            .expect("answers")
    };
    health().await;
    // every silent one is closed by the server once its time to speak has passed
    let deadline = jsae_net::accept::FIRST_BYTES_TIMEOUT + std::time::Duration::from_secs(5);
    for stream in &mut silent {
        let mut byte = [0u8; 1];
        let read = tokio::time::timeout(deadline, stream.read(&mut byte))
            .await
            .expect("closed in time");
        assert!(matches!(read, Ok(0) | Err(_)), "{read:?}");
    }
    health().await;
    learner.stop().await.expect("learner stops");
}
