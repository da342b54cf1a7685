//! A learner service killed mid-run (its task aborted, as `kill -9` would end the process)
//! and started again on the same run directory goes on with the state its checkpoint saved:
//! the optimiser, the reward scaler, the step accounts and the wall time, over real gRPC on
//! 127.0.0.1 (the harness is `jsae_tests::services`).

use jsae_learner::Learner;
use jsae_run_dir::MetricsTable;
use jsae_run_dir::{LatestCheckpoint, RunDir, Weights};
use jsae_settings::{Algo, EnvName, TrainConfig};
use jsae_tests::services::*;

/// A learner of `config` resumed from `saved`, with the wall time it returned.
fn resumed(config: &TrainConfig, saved: &LatestCheckpoint) -> (Learner, f64) {
    let mut learner = Learner::for_run(config);
    let wall = learner
        .resume(saved)
        .expect("the checkpoint resumes")
        .expect("it carries the training state");
    (learner, wall)
}

fn column(table: &MetricsTable, name: &str) -> Vec<f64> {
    table
        .column(name)
        .into_iter()
        .map(|v| v.expect("a value"))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_learner_killed_after_a_checkpoint_restarts_with_the_state_it_saved() {
    let mut c = config(EnvName::Gridworld, Algo::Ppo, "restart-state");
    c.env_steps = 50 * c.round_steps() as u64;
    let out = RunDir::new(&c.out);
    let n = c.round_steps() / 2;
    // one actor incarnation's fragments, its claim growing by n each
    let fragments = |from: usize, count: usize| -> Vec<_> {
        (from..from + count)
            .map(|i| claimed_fragment(&c, 3, 0xABC, ((i + 1) * n) as u64, n, 0))
            .collect()
    };

    let first = start_learner(&c, None).await;
    push_fragments(&first.url, fragments(0, 4))
        .await
        .expect("accepted");
    wait_for_rows(&c.out, 2).await;
    first.handle.abort(); // gone without a word: no final checkpoint, no drain
    let saved = out
        .checkpoints()
        .read_latest_checkpoint(Weights::Policy)
        .expect("the checkpoint of update 2");
    assert_eq!(saved.version, 2);

    // the restarted learner publishes the saved version, with the saved state
    let second = start_learner(&c, None).await;
    let mut watch = watch_policy(&second.url, 3).await;
    assert_eq!(until_snapshot(&mut watch, 0).await, Ok(2));
    let rewritten = out
        .checkpoints()
        .read_latest_checkpoint(Weights::Policy)
        .expect("the restarted learner's first checkpoint");
    let (before, saved_wall) = resumed(&c, &saved);
    let (after, restarted_wall) = resumed(&c, &rewritten);
    assert_eq!(after.env_steps(), 4 * n as u64);
    assert_eq!(after.updates(), 2);
    // everything but the wall time, which went on
    let state = |l: &Learner| l.training_state(0.0).expect("a state");
    assert_eq!(state(&after), state(&before));
    assert_eq!(rewritten.weights, saved.weights);
    assert!(
        restarted_wall >= saved_wall && saved_wall > 0.0,
        "{restarted_wall} after {saved_wall}"
    );

    // the same actor incarnation goes on; its steps count on from the checkpoint
    push_fragments(&second.url, fragments(4, 2))
        .await
        .expect("accepted");
    wait_for_rows(&c.out, 3).await;
    second.stop().await.expect("stops cleanly");
    let table = MetricsTable::read(&out.metrics_csv()).expect("metrics.csv");
    assert_eq!(column(&table, "update"), [1.0, 2.0, 3.0], "no update twice");
    assert_eq!(
        column(&table, "env_steps"),
        [2.0 * n as f64, 4.0 * n as f64, 6.0 * n as f64]
    );
    let wall = column(&table, "wall_seconds");
    assert!(
        wall[2] >= wall[1] && wall[2] >= saved_wall,
        "wall time counts on across the restart: {wall:?}"
    );
}
