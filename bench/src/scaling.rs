//! `jsae bench --scaling [--actors 1,2,4,8]`: the actor ladder. HalfCheetah PPO end to end as
//! separate processes (learner + N actors over loopback gRPC, as `jsae train --actors N`
//! starts them), every actor with the default 16 environments x 128 steps, so the learner's
//! batch is one rollout of every actor (N x 2,048 steps: the batch grows with the actors, the
//! learner counting them by their policy streams), with `rollouts_per_policy` 1 and 2 (2: the
//! next rollout is collected while the learner updates). From 2 actors on, two more rows keep
//! the number of minibatches instead of their size (`ppo.minibatches` = 32, the 64 of one
//! actor's 2,048 steps): the minibatch grows with the batch and its rows are split between
//! the learner's threads; with `rollouts_per_policy` 2 and 3 (3: a whole round waits for the
//! learner when it finishes, at lag 2). Beside the ladder, measured in the same run:
//! - raw stepping: our environment with random actions on one thread, the unit of the ratios;
//! - the learner's limit: env steps per second its PPO update takes in at each batch size
//!   (synthetic fragments ingested in one process: validation, GAE, every epoch, the
//!   snapshot; gRPC decoding and the checkpoint left out), the rate no number of actors can
//!   pass;
//! - one process (`--one-process`, one actor's batch).
//!
//! The rate is the steady state: env steps between the first and the last update over the
//! wall time between them (start-up and the final evaluation left out). Lag and drops are
//! the run's, from `metrics.csv`.

use std::path::{Path, PathBuf};

use jsae_envs::{EnvName, Robot};
use jsae_run_dir::MetricsTable;
use jsae_run_dir::RunDir;
use jsae_settings::UpdatePath;
use jsae_settings::{Algo, TrainConfig};

use jsae_train::launch;
use jsae_train::progress::Progress;
use jsae_train::train_one_process;

/// Env steps of one actor's rollout under the defaults (16 x 128).
const ROLLOUT: usize = 2048;
/// `ppo.minibatches` of the rows that keep the count: HalfCheetah's minibatch of 64 in one
/// actor's rollout.
const MINIBATCHES: usize = 32;

/// One measured set-up.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalingRow {
    /// "one process" or "processes".
    pub mode: &'static str,
    /// Actors.
    pub actors: usize,
    /// The learner's batch (one rollout of every actor).
    pub batch: usize,
    /// Rollouts an actor sends per policy version (2: overlapped with the update).
    pub rollouts_per_policy: usize,
    /// Samples per minibatch (64, or the batch over `ppo.minibatches`).
    pub minibatch: usize,
    /// Steady-state env steps per second.
    pub steps_per_s: f64,
    /// The learner's limit at this batch (env steps per second its update takes in).
    pub learner_limit: f64,
    /// Mean policy lag over the run's updates.
    pub lag_mean: f64,
    /// Fragments dropped for lag, and for an outdated embedding.
    pub dropped: (u64, u64),
}

/// Steady-state rate, mean lag and drops from a run's `metrics.csv`.
fn steady_state(dir: &Path) -> anyhow::Result<(f64, f64, (u64, u64))> {
    let table = MetricsTable::read(&RunDir::new(dir).metrics_csv())?;
    let col = |name: &str| -> Vec<f64> { table.column(name).into_iter().flatten().collect() };
    let (steps, wall, lag) = (
        col("env_steps"),
        col("wall_seconds"),
        col("policy_lag_mean"),
    );
    anyhow::ensure!(
        steps.len() >= 3 && wall.len() == steps.len(),
        "too few updates in {}",
        dir.display()
    );
    let n = steps.len() - 1;
    let rate = (steps[n] - steps[0]) / (wall[n] - wall[0]).max(1e-9);
    let lag_mean = lag.iter().sum::<f64>() / lag.len().max(1) as f64;
    let last = |name: &str| col(name).last().copied().unwrap_or(0.0) as u64;
    Ok((
        rate,
        lag_mean,
        (last("dropped_lag"), last("dropped_embedding")),
    ))
}

/// One rung's settings.
#[derive(Debug, Clone, Copy)]
struct Rung {
    actors: usize,
    rollouts_per_policy: usize,
    minibatches: Option<usize>,
    /// Every actor's stepping threads (0: the run's rule).
    step_threads: usize,
}

fn config(rung: Rung, env_steps: u64, out: PathBuf) -> TrainConfig {
    let Rung {
        actors,
        rollouts_per_policy,
        minibatches,
        step_threads,
    } = rung;
    let mut c = TrainConfig::defaults(EnvName::HalfCheetah, Algo::Ppo);
    c.step_threads = step_threads;
    c.ppo.minibatches = minibatches;
    c.actors = actors;
    c.rollouts_per_policy = rollouts_per_policy;
    c.env_steps = env_steps;
    c.eval_episodes = 1;
    c.out = out;
    c
}

/// Env steps of a run of `actors`: enough updates for a steady state at any batch.
fn run_steps(actors: usize, quick: bool) -> u64 {
    let batch = (actors * ROLLOUT) as u64;
    if quick {
        (8 * batch).max(40_960)
    } else {
        (30 * batch).max(204_800)
    }
}

/// The learner's limit at a batch of `actors` rollouts: env steps per second, and the
/// minibatch it ran.
fn learner_limit(actors: usize, minibatches: Option<usize>, quick: bool) -> (f64, usize) {
    let b = super::learner::bench_batch(
        EnvName::HalfCheetah,
        Algo::Ppo,
        if quick { 2 } else { 5 },
        UpdatePath::Fused,
        actors * ROLLOUT,
        minibatches,
    );
    (b.batch as f64 / (b.update_ms / 1e3).max(1e-9), b.minibatch)
}

/// Measures one process and every rung of the ladder.
pub fn measure(
    ladder: &[usize],
    step_threads: usize,
    quick: bool,
) -> anyhow::Result<Vec<ScalingRow>> {
    let root = std::env::temp_dir().join(format!("jsae-bench-scaling-{}", std::process::id()));
    let rows = measure_in(&root, ladder, step_threads, quick);
    let _ = std::fs::remove_dir_all(&root);
    rows
}

fn measure_in(
    root: &Path,
    ladder: &[usize],
    step_threads: usize,
    quick: bool,
) -> anyhow::Result<Vec<ScalingRow>> {
    let exe = launch::current_exe()?;
    let mut rows = Vec::new();
    let one_rung = Rung {
        actors: 1,
        rollouts_per_policy: 1,
        minibatches: None,
        step_threads,
    };
    let one = config(one_rung, run_steps(1, quick), root.join("one-process"));
    let mut progress = Progress::new(one.env_steps, true);
    train_one_process(&one, &mut progress)?;
    let (rate, lag, dropped) = steady_state(&one.out)?;
    let (limit, minibatch) = learner_limit(1, None, quick);
    rows.push(ScalingRow {
        mode: "one process",
        actors: 1,
        batch: ROLLOUT,
        rollouts_per_policy: 1,
        minibatch,
        steps_per_s: rate,
        learner_limit: limit,
        lag_mean: lag,
        dropped,
    });
    for &actors in ladder {
        let mut rungs = vec![(1, None), (2, None)];
        if actors > 1 {
            rungs.extend([(2, Some(MINIBATCHES)), (3, Some(MINIBATCHES))]);
        }
        let mut limits = std::collections::HashMap::new();
        for (rollouts_per_policy, minibatches) in rungs {
            let rung = Rung {
                actors,
                rollouts_per_policy,
                minibatches,
                step_threads,
            };
            let (limit, minibatch) = *limits
                .entry(minibatches)
                .or_insert_with(|| learner_limit(actors, minibatches, quick));
            let name = match minibatches {
                Some(n) => format!("a{actors}-r{rollouts_per_policy}-m{n}"),
                None => format!("a{actors}-r{rollouts_per_policy}"),
            };
            let c = config(rung, run_steps(actors, quick), root.join(name));
            let mut progress = Progress::new(c.env_steps, true);
            launch::train_processes(&c, &jsae_train::RunOptions::default(), &exe, &mut progress)?;
            let (rate, lag, dropped) = steady_state(&c.out)?;
            rows.push(ScalingRow {
                mode: "processes",
                actors,
                batch: actors * ROLLOUT,
                rollouts_per_policy,
                minibatch,
                steps_per_s: rate,
                learner_limit: limit,
                lag_mean: lag,
                dropped,
            });
        }
    }
    Ok(rows)
}

/// The ladder's actor counts by default: 1, 2, 4, ... up to the machine's cores (2 at least).
pub fn default_ladder() -> Vec<usize> {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    std::iter::successors(Some(1usize), |a| Some(a * 2))
        .take_while(|&a| a <= cores.max(2))
        .collect()
}

/// Runs the measurement and formats the table.
pub fn run(ladder: &[usize], step_threads: usize, quick: bool) -> String {
    let raw = super::mujoco::env_rate(Robot::HalfCheetah, if quick { 20_000 } else { 100_000 });
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let mut out = format!(
        "HalfCheetah PPO end to end, {cores} cores; every actor 16 envs x 128 steps, the batch one \
         rollout of every actor; raw stepping (our env, random actions, one thread, this run): \
         {raw:.0} steps/s; actors' stepping threads: {}\n",
        match step_threads {
            0 => "the run's rule (cores less one, over the actors)".to_string(),
            n => n.to_string(),
        }
    );
    out.push_str(&format!(
        "{:<12} {:>6} {:>6} {:>9} {:>9} {:>12} {:>7} {:>13} {:>8} {:>6} {:>8} {:>9}\n",
        "mode",
        "actors",
        "batch",
        "rollouts",
        "minibatch",
        "env-steps/s",
        "/raw",
        "learner limit",
        "/limit",
        "lag",
        "dropped",
        "dropped e"
    ));
    match measure(ladder, step_threads, quick) {
        Ok(rows) => {
            for r in rows {
                out.push_str(&format!(
                    "{:<12} {:>6} {:>6} {:>9} {:>9} {:>12.0} {:>7.2} {:>13.0} {:>8.2} {:>6.2} {:>8} {:>9}\n",
                    r.mode,
                    r.actors,
                    r.batch,
                    r.rollouts_per_policy,
                    r.minibatch,
                    r.steps_per_s,
                    r.steps_per_s / raw,
                    r.learner_limit,
                    r.steps_per_s / r.learner_limit,
                    r.lag_mean,
                    r.dropped.0,
                    r.dropped.1
                ));
            }
        }
        Err(e) => out.push_str(&format!("scaling not measured: {e}\n")),
    }
    out.push_str(
        "batch: one rollout of every actor; rollouts: an actor may have out before a newer \
         policy answers them (2: the next rollout is collected while the learner updates); \
         minibatch: samples per gradient step (64, or the batch over ppo.minibatches = 32, \
         split between the learner's threads); env-steps/s: between the first and the last update; /raw: over one core's raw \
         stepping; learner limit: env steps/s the PPO update takes in at this batch (in one \
         process, synthetic fragments; no actor count can pass it); lag: mean policy lag of \
         the fragments; dropped, dropped e: fragments dropped for lag, for an outdated \
         embedding\n",
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_ladder_doubles_up_to_the_cores() {
        let ladder = default_ladder();
        assert_eq!(&ladder[..2], &[1, 2]);
        assert!(ladder.windows(2).all(|w| w[1] == 2 * w[0]));
        assert!(run_steps(8, false) >= 30 * 8 * ROLLOUT as u64);
    }
}
