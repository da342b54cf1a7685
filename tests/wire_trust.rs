//! What the learner believes of a well-formed message, over real gRPC on 127.0.0.1: an
//! embedding version the embedder never published, a step claim of 10^12, a reward of 3e38,
//! an evaluation report from an actor nobody asked, and a restarted actor reusing its id. The
//! harness is `jsae_tests::services`.

use jsae_run_dir::MetricsTable;
use jsae_run_dir::RunDir;
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_tests::services::*;
use jsae_wire::pb;
use tonic::Code;

/// The env steps of every metrics.csv row so far.
fn env_steps_rows(c: &TrainConfig) -> Vec<u64> {
    let table = MetricsTable::read(&RunDir::new(&c.out).metrics_csv()).expect("metrics.csv");
    table
        .column("env_steps")
        .into_iter()
        .map(|v| v.expect("env steps") as u64)
        .collect()
}

fn half_batch(c: &TrainConfig) -> usize {
    c.round_steps() / 2
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fragment_of_an_embedding_version_never_published_is_refused_and_training_goes_on() {
    // with an embedder: it has published version 1
    let mut c = config(EnvName::Gridworld, Algo::Jsae, "trust-embedding");
    c.embedding.pretrain_transitions = 512;
    c.embedding.pretrain_epochs = 1;
    let embedder = start_embedder(&c).await;
    pretrain_to_version_one(&embedder.url).await;
    let learner = start_learner(&c, Some(embedder.url.clone())).await;
    let n = half_batch(&c);
    let genuine = |claim: u64| claimed_fragment(&c, 1, 7, claim, n, 1);
    assert_eq!(
        push_fragments(&learner.url, vec![genuine(n as u64)])
            .await
            .expect("accepted"),
        1,
        "version 1 is published"
    );
    let forged = claimed_fragment(&c, 66, 1, n as u64, n, 1 << 63);
    assert_refused(
        push_fragments(&learner.url, vec![forged]).await,
        Code::InvalidArgument,
        "unknown embedding version 9223372036854775808",
    );
    // the genuine stream goes on: the batch completes and the policy is updated
    push_all(&learner.url, vec![genuine(2 * n as u64)]).await;
    wait_for_rows(&c.out, 1).await;
    assert_eq!(env_steps_rows(&c), [2 * n as u64]);
    learner.stop().await.expect("learner stops");
    embedder.stop().await.expect("embedder stops");

    // without an embedder only version 0 is known
    let c = config(EnvName::Gridworld, Algo::Ppo, "trust-no-embedder");
    let learner = start_learner(&c, None).await;
    let f = claimed_fragment(&c, 1, 7, 8, 8, 0);
    push_all(&learner.url, vec![f]).await;
    let f = claimed_fragment(&c, 1, 7, 16, 8, 1);
    assert_refused(
        push_fragments(&learner.url, vec![f]).await,
        Code::InvalidArgument,
        "unknown embedding version 1",
    );
    learner.stop().await.expect("learner stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_forged_step_claim_neither_ends_the_run_nor_opens_an_evaluation() {
    let mut c = config(EnvName::Gridworld, Algo::Ppo, "trust-claim");
    c.env_steps = 4 * c.round_steps() as u64;
    let learner = start_learner(&c, None).await;
    let mut watch = watch_policy(&learner.url, 66).await;
    let n = half_batch(&c);
    let forged = claimed_fragment(&c, 66, 1, 1_000_000_000_000, n, 0);
    let genuine = claimed_fragment(&c, 1, 7, n as u64, n, 0);
    push_all(&learner.url, vec![forged, genuine]).await;
    // the update after the forged fragment comes, and no evaluation request before it
    match until_snapshot(&mut watch, 1).await {
        Ok(version) => assert_eq!(version, 1),
        Err(request) => panic!("the forged claim opened an evaluation: {request:?}"),
    }
    wait_for_rows(&c.out, 1).await;
    assert_eq!(
        env_steps_rows(&c),
        [2 * n as u64],
        "the forged fragment counts its length"
    );
    learner.stop().await.expect("learner stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_finite_but_absurd_reward_is_refused() {
    let c = config(EnvName::Gridworld, Algo::Ppo, "trust-reward");
    let learner = start_learner(&c, None).await;
    let mut poisoned = claimed_fragment(&c, 1, 7, 8, 8, 0);
    poisoned.rewards[3] = 3e38;
    assert_refused(
        push_fragments(&learner.url, vec![poisoned]).await,
        Code::InvalidArgument,
        "rewards: value 3",
    );
    let mut large = claimed_fragment(&c, 1, 7, 8, 8, 0);
    large.rewards[3] = c.ppo.max_abs_reward;
    assert_eq!(
        push_fragments(&learner.url, vec![large])
            .await
            .expect("accepted"),
        1,
        "the bound itself passes"
    );
    learner.stop().await.expect("learner stops");
}

/// A plausible report of `episodes` episodes.
fn report(actor_id: u64, request_id: u64, episodes: u32) -> pb::EvalReport {
    let episode = pb::EpisodeStat {
        ret: 1.0,
        length: 10,
        success: Some(true),
    };
    pb::EvalReport {
        actor_id,
        policy_version: 1,
        embedding_version: 0,
        episodes: vec![episode; episodes as usize],
        request_id,
        stochastic_episodes: vec![],
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_asked_actor_sees_the_evaluation_request_and_only_its_report_counts() {
    let mut c = config(EnvName::Gridworld, Algo::Ppo, "trust-eval");
    c.env_steps = c.round_steps() as u64;
    let learner = start_learner(&c, None).await;
    let n = half_batch(&c);
    let fragments = vec![
        claimed_fragment(&c, 4, 7, n as u64, n, 0),
        claimed_fragment(&c, 9, 7, n as u64, n, 0),
    ];
    push_all(&learner.url, fragments).await;
    // actor 9's fragment reached the run's env steps: it is asked
    let mut asked = watch_policy(&learner.url, 9).await;
    let request = until_snapshot(&mut asked, u64::MAX)
        .await
        .expect_err("an evaluation request");
    assert_eq!(request.actor_id, 9);
    // actor 4 gets the snapshot and nothing more
    let mut other = watch_policy(&learner.url, 4).await;
    assert_eq!(until_snapshot(&mut other, 1).await, Ok(1));
    let more = tokio::time::timeout(std::time::Duration::from_millis(500), other.message()).await;
    assert!(more.is_err(), "another actor's stream carried {more:?}");

    let mut client = pb::learner_client::LearnerClient::connect(learner.url.clone())
        .await
        .expect("connect");
    let wrong_id = client
        .report_eval(report(
            9,
            request.request_id.wrapping_add(1),
            request.episodes,
        ))
        .await
        .expect_err("an unknown request");
    assert_eq!(wrong_id.code(), Code::FailedPrecondition, "{wrong_id:?}");
    let wrong_actor = client
        .report_eval(report(4, request.request_id, request.episodes))
        .await
        .expect_err("not the asked actor");
    assert_eq!(
        wrong_actor.code(),
        Code::PermissionDenied,
        "{wrong_actor:?}"
    );
    // what the run cannot have produced: another episode count, an episode past the time
    // limit with an absurd return, an embedding version in a run without an embedder, a
    // policy version never published
    let good = || report(9, request.request_id, request.episodes);
    let mut forged = Vec::new();
    let mut r = good();
    r.episodes.pop();
    forged.push((r, "episodes: expected"));
    let mut r = good();
    r.episodes[0].length = u32::MAX;
    r.episodes[0].ret = 1.7e308;
    forged.push((r, "episodes: episode 0"));
    let mut r = good();
    r.stochastic_episodes = vec![r.episodes[0]; request.episodes as usize + 1];
    forged.push((r, "stochastic_episodes: expected"));
    let mut r = good();
    r.embedding_version = 4242;
    forged.push((r, "embedding version 4242"));
    let mut r = good();
    r.policy_version = 77;
    forged.push((r, "policy version 77"));
    for (r, words) in forged {
        let refused = client.report_eval(r).await.expect_err(words);
        assert_eq!(refused.code(), Code::InvalidArgument, "{refused:?}");
        assert!(
            refused.message().contains(words),
            "{refused:?} lacks {words:?}"
        );
    }
    client
        .report_eval(good())
        .await
        .expect("the asked actor's report");
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    assert_eq!(summary.env_steps, 2 * n as u64);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_asked_actor_that_dies_before_it_reports_is_replaced_and_the_run_ends() {
    let mut c = config(EnvName::Gridworld, Algo::Ppo, "trust-eval-replaced");
    c.env_steps = c.round_steps() as u64;
    let learner = start_learner(&c, None).await;
    let n = half_batch(&c);
    // actor 9 (this test) is alive and its fragment reaches the run's env steps
    let mut asked = watch_policy(&learner.url, 9).await;
    let fragments = vec![
        claimed_fragment(&c, 9, 7, n as u64, n, 0),
        claimed_fragment(&c, 9, 7, 2 * n as u64, n, 0),
    ];
    push_all(&learner.url, fragments).await;
    let request = until_snapshot(&mut asked, u64::MAX)
        .await
        .expect_err("an evaluation request");
    assert_eq!(request.actor_id, 9);
    // a real actor joins; actor 9 dies without a report: its stream closes
    let actor = start_actor(&c, 0, None, &learner.url);
    drop(asked);
    let summary = tokio::time::timeout(std::time::Duration::from_secs(120), learner.join())
        .await
        .expect("the run ends in time")
        .expect("learner")
        .expect("the run ended");
    assert_eq!(summary.env_steps, 2 * n as u64);
    assert_eq!(summary.eval_episodes, c.eval_episodes);
    actor.join().await.expect("the actor finished");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_incarnations_of_one_actor_id_are_both_counted() {
    let mut c = config(EnvName::Gridworld, Algo::Ppo, "trust-incarnations");
    c.env_steps = 4 * c.round_steps() as u64;
    let learner = start_learner(&c, None).await;
    let n = half_batch(&c);
    // actor 0, then actor 0 again after a restart: each counts from zero
    let fragments = vec![
        claimed_fragment(&c, 0, 0x1111, n as u64, n, 0),
        claimed_fragment(&c, 0, 0x2222, n as u64, n, 0),
    ];
    push_all(&learner.url, fragments).await;
    wait_for_rows(&c.out, 1).await;
    assert_eq!(env_steps_rows(&c), [2 * n as u64]);
    learner.stop().await.expect("learner stops");
}
