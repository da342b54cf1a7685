//! The learner counts its actors by their open policy streams, whatever the settings say:
//! two actors of a run whose settings say one make one batch of two rollouts, or, with the
//! batch shared (`batch_envs`), share its batch, each stepping half of its environments (lag
//! 0, nothing dropped either way); an actor that is connected but silent holds no round past
//! its deadline.

use jsae_actor::service::{ActorExit, ActorReport};
use jsae_run_dir::MetricsTable;
use jsae_run_dir::RunDir;
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_tests::services::*;

/// A column of the run's metrics.csv, one value per update.
fn metric(out: &std::path::Path, column: &str) -> Vec<f64> {
    let table = MetricsTable::read(&RunDir::new(out).metrics_csv()).expect("metrics.csv");
    table.column(column).into_iter().flatten().collect()
}

/// Env steps between consecutive metrics rows.
fn batches(out: &std::path::Path) -> Vec<u64> {
    let steps = metric(out, "env_steps");
    steps.windows(2).map(|w| (w[1] - w[0]) as u64).collect()
}

fn lag_max(out: &std::path::Path) -> f64 {
    metric(out, "policy_lag_max")
        .into_iter()
        .fold(0.0, f64::max)
}

/// Two actors started by hand for a run whose settings say one: both finish the run, nothing
/// dropped, every fragment answered by its own update (lag 0); their reports.
async fn two_actors_at_lag_zero(c: &TrainConfig) -> [ActorReport; 2] {
    let learner = start_learner(c, None).await;
    let a = start_actor(c, 1, None, &learner.url);
    let b = start_actor(c, 2, None, &learner.url);
    let reports = [a.join().await.expect("a"), b.join().await.expect("b")];
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    for r in &reports {
        assert_eq!(r.exit, ActorExit::Finished, "{r:?}");
    }
    assert_eq!(summary.dropped_lag, 0, "{summary:?}");
    assert_eq!(
        lag_max(&c.out),
        0.0,
        "every fragment answered by its own update"
    );
    reports
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_actors_of_a_one_actor_run_share_its_batch_at_lag_zero() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "roster-shared");
    c.actors = 1; // what a user launching actors by hand leaves as it is
    c.env_steps = 4_096;
    c.policy_wait_ms = 10_000;
    c.batch_envs = Some(c.envs_per_actor);
    let rollout = (c.envs_per_actor * c.rollout_len) as u64;
    let reports = two_actors_at_lag_zero(&c).await;
    let sizes = batches(&c.out);
    // a batch of one actor's rollout whoever is present (the first rounds: the first actor's
    // whole rollout and the second's share, until the round that re-shares ends)
    let single = sizes.iter().skip(2).filter(|&&s| s == rollout).count();
    assert!(single + 2 >= sizes.len(), "batches of {rollout}: {sizes:?}");
    // both stepped about half: one fragment per environment stepped
    let rounds = sizes.len() as u64;
    for r in &reports {
        let per_round = r.fragments as f64 / rounds as f64;
        assert!(
            (per_round - c.envs_per_actor as f64 / 2.0).abs() <= 1.0,
            "{} fragments in {rounds} rounds: {r:?}",
            r.fragments
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_actors_of_a_one_actor_run_make_one_batch_of_two_rollouts_at_lag_zero() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "roster-by-hand");
    c.actors = 1; // what a user launching actors by hand leaves as it is
    c.env_steps = 6_144;
    // a round's deadline (half of this) far beyond a rollout even on a loaded machine: both
    // actors are alive, so every round must wait for both
    c.policy_wait_ms = 10_000;
    let rollout = (c.envs_per_actor * c.rollout_len) as u64;
    two_actors_at_lag_zero(&c).await;
    let sizes = batches(&c.out);
    // the first round may close before the second actor's stream is open
    let doubled = sizes.iter().skip(1).filter(|&&s| s == 2 * rollout).count();
    assert!(
        doubled + 1 >= sizes.len(),
        "batches of two rollouts ({}): {sizes:?}",
        2 * rollout
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_connected_actor_that_sends_nothing_holds_no_round_past_its_deadline() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "roster-silent");
    c.env_steps = 4_096;
    c.policy_wait_ms = 1_000;
    let learner = start_learner(&c, None).await;
    // actor 77 says it is there and never sends a fragment
    let silent = watch_policy(&learner.url, 77).await;
    let a = start_actor(&c, 1, None, &learner.url);
    let ra = tokio::time::timeout(std::time::Duration::from_secs(120), a.join())
        .await
        .expect("the run did not wait on the silent actor for good")
        .expect("actor 1");
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    drop(silent);
    assert_eq!(ra.exit, ActorExit::Finished);
    assert!(summary.env_steps >= c.env_steps, "{summary:?}");
    assert_eq!(summary.dropped_lag, 0, "{summary:?}");
    // after the first round's deadline the silent actor is out of the batch: one rollout each
    let rollout = (c.envs_per_actor * c.rollout_len) as u64;
    let sizes = batches(&c.out);
    assert!(
        sizes.iter().skip(1).all(|&s| s == rollout),
        "one rollout per batch once the silent actor is left out: {sizes:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_actor_of_a_shared_batch_leaves_its_share_to_the_survivor() {
    let mut c = config(EnvName::GridworldDiscrete, Algo::Ppo, "roster-shared-kill");
    c.env_steps = 6_144;
    c.policy_wait_ms = 1_000;
    c.batch_envs = Some(c.envs_per_actor);
    let rollout = (c.envs_per_actor * c.rollout_len) as u64;
    let learner = start_learner(&c, None).await;
    let a = start_actor(&c, 1, None, &learner.url);
    let b = start_actor(&c, 2, None, &learner.url);
    wait_for_rows(&c.out, 4).await;
    a.handle.abort(); // gone mid-run, its stream closed
    let rb = b.join().await.expect("actor 2");
    let summary = learner
        .join()
        .await
        .expect("learner")
        .expect("the run ended");
    assert_eq!(rb.exit, ActorExit::Finished);
    assert!(summary.env_steps >= c.env_steps, "{summary:?}");
    assert_eq!(summary.dropped_lag, 0, "{summary:?}");
    // the survivor steps all of the batch's environments: whole batches again, at lag 0
    let sizes = batches(&c.out);
    let tail = &sizes[sizes.len().saturating_sub(5)..];
    assert!(tail.iter().all(|&s| s == rollout), "{sizes:?}");
    let lags = metric(&c.out, "policy_lag_max");
    assert!(
        lags[lags.len().saturating_sub(5)..]
            .iter()
            .all(|&l| l == 0.0),
        "{lags:?}"
    );
}
