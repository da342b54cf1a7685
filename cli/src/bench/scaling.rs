//! `jsae bench --scaling`: end-to-end HalfCheetah PPO env-steps/s as separate processes
//! (learner + actors over loopback gRPC) with 1 and 2 actors (4 where there are 4 cores)
//! sharing one batch of 2,048 steps, with and without collecting the next rollout while the
//! learner updates (`rollouts_per_policy` 1 and 2), beside one process and beside our
//! environment's raw random-action stepping measured in the same run.
//!
//! The rate is the steady state: env steps between the first and the last update over the
//! wall time between them (start-up and the final evaluation left out). Lag and drops are
//! the run's, from `metrics.csv`.

use std::path::{Path, PathBuf};

use jsae_envs::{EnvName, Robot};
use jsae_learner::MetricsTable;
use jsae_proto::run_dir::RunDir;
use jsae_proto::settings::{Algo, TrainConfig};

use crate::launch;
use crate::progress::Progress;
use crate::train::train_one_process;

/// One measured set-up.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalingRow {
    /// "one process" or "processes".
    pub mode: &'static str,
    /// Actors.
    pub actors: usize,
    /// Environments per actor.
    pub envs: usize,
    /// Rollouts an actor sends per policy version (2: overlapped with the update).
    pub rollouts_per_policy: usize,
    /// Steady-state env steps per second.
    pub steps_per_s: f64,
    /// Mean policy lag over the run's updates.
    pub lag_mean: f64,
    /// Fragments dropped for lag.
    pub dropped_lag: u64,
}

/// Steady-state rate, mean lag and drops from a run's `metrics.csv`.
fn steady_state(dir: &Path) -> anyhow::Result<(f64, f64, u64)> {
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
    let dropped = col("dropped_lag").last().copied().unwrap_or(0.0) as u64;
    Ok((rate, lag_mean, dropped))
}

fn config(actors: usize, rollouts_per_policy: usize, env_steps: u64, out: PathBuf) -> TrainConfig {
    let mut c = TrainConfig::defaults(EnvName::HalfCheetah, Algo::Ppo);
    c.actors = actors;
    c.envs_per_actor = (c.envs_per_actor / actors).max(1);
    c.rollouts_per_policy = rollouts_per_policy;
    c.env_steps = env_steps;
    c.eval_episodes = 1;
    c.out = out;
    c
}

/// Measures every set-up with `env_steps` per run.
pub fn measure(env_steps: u64) -> anyhow::Result<Vec<ScalingRow>> {
    let root = std::env::temp_dir().join(format!("jsae-bench-scaling-{}", std::process::id()));
    let rows = measure_in(&root, env_steps);
    let _ = std::fs::remove_dir_all(&root);
    rows
}

fn measure_in(root: &Path, env_steps: u64) -> anyhow::Result<Vec<ScalingRow>> {
    let exe = launch::current_exe()?;
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let mut rows = Vec::new();
    let mut progress = Progress::new(env_steps, true);
    let one = config(1, 1, env_steps, root.join("one-process"));
    train_one_process(&one, &mut progress)?;
    let (rate, lag, dropped) = steady_state(&one.out)?;
    rows.push(ScalingRow {
        mode: "one process",
        actors: 1,
        envs: one.envs_per_actor,
        rollouts_per_policy: 1,
        steps_per_s: rate,
        lag_mean: lag,
        dropped_lag: dropped,
    });
    let actor_counts: Vec<usize> = [1, 2, 4]
        .into_iter()
        .filter(|&a| a <= cores.max(2))
        .collect();
    for actors in actor_counts {
        for rollouts in [1, 2] {
            let c = config(
                actors,
                rollouts,
                env_steps,
                root.join(format!("a{actors}-r{rollouts}")),
            );
            launch::train_processes(
                &c,
                &crate::train::RunOptions::default(),
                &exe,
                &mut progress,
            )?;
            let (rate, lag, dropped) = steady_state(&c.out)?;
            rows.push(ScalingRow {
                mode: "processes",
                actors,
                envs: c.envs_per_actor,
                rollouts_per_policy: rollouts,
                steps_per_s: rate,
                lag_mean: lag,
                dropped_lag: dropped,
            });
        }
    }
    Ok(rows)
}

/// Runs the measurement and formats the table.
pub fn run(quick: bool) -> String {
    let env_steps = if quick { 40_960 } else { 204_800 };
    let raw = super::mujoco::env_rate(Robot::HalfCheetah, if quick { 20_000 } else { 100_000 });
    let mut out = format!(
        "HalfCheetah PPO end to end, batch 2,048, {env_steps} env steps per run; raw stepping \
         (our env, random actions, one thread, this run): {raw:.0} steps/s\n"
    );
    out.push_str(&format!(
        "{:<12} {:>6} {:>5} {:>9} {:>12} {:>7} {:>8} {:>8}\n",
        "mode", "actors", "envs", "rollouts", "env-steps/s", "/raw", "lag", "dropped"
    ));
    match measure(env_steps) {
        Ok(rows) => {
            for r in rows {
                out.push_str(&format!(
                    "{:<12} {:>6} {:>5} {:>9} {:>12.0} {:>7.3} {:>8.2} {:>8}\n",
                    r.mode,
                    r.actors,
                    r.envs,
                    r.rollouts_per_policy,
                    r.steps_per_s,
                    r.steps_per_s / raw,
                    r.lag_mean,
                    r.dropped_lag
                ));
            }
        }
        Err(e) => out.push_str(&format!("scaling not measured: {e}\n")),
    }
    out.push_str(
        "envs: per actor (the batch stays 2,048); rollouts: an actor may have out before a newer \
         policy answers them (2: the \
         next rollout is collected while the learner updates); env-steps/s: between the first \
         and the last update; lag: mean policy lag of the fragments; dropped: fragments \
         dropped for lag\n",
    );
    out
}
