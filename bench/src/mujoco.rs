//! `jsae bench --mujoco`: env-steps per second on HalfCheetah and Ant, one core, measured in
//! one run so the ratios mean something:
//! (a) our environment stepped with random actions (no inference);
//! (b) the actor worker with batched `phi -> pi_i -> f` inference across K environments
//!     (PPO: policy only; JSAE: phi, the Gaussian over E, the decoder f), rollouts as in
//!     training, stepping on one thread, and for JSAE also on one thread per core;
//! (c) a raw mujoco-rs loop: set ctrl, `mj_step` x 5, nothing else;
//! (d) Gymnasium's Python step rate (scripts/python/gymnasium_steprate.py in the reference
//!     venv; skipped, and said so, where the venv cannot be made).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use jsae_nn::DeviceKind;
use jsae_settings::{Algo, TrainConfig};
use mujoco_rs::prelude::MjData;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::trained_worker;
use jsae_envs::mujoco::FRAME_SKIP;
use jsae_envs::{ActionRef, Env, EnvName, MujocoConfig, MujocoEnv, Robot};

/// Rates of one robot, env steps per second.
#[derive(Debug, Clone, Copy)]
pub struct MujocoRates {
    /// (a) our env, random actions.
    pub env_random: f64,
    /// (b) actor with PPO inference, stepping on one thread.
    pub actor_ppo: f64,
    /// (b) actor with JSAE inference, stepping on one thread.
    pub actor_jsae: f64,
    /// (b) actor with JSAE inference, stepping on one thread per core.
    pub actor_jsae_cores: f64,
    /// Threads of the last measurement.
    pub cores: usize,
    /// (c) raw mujoco-rs.
    pub raw: f64,
    /// (d) Gymnasium (None: not measured).
    pub gymnasium: Option<f64>,
}

fn raw_rate(robot: Robot, steps: usize) -> f64 {
    let model = robot.model();
    let mut data = MjData::new(model.clone());
    let nu = model.ffi().nu as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    data.forward();
    let t = Instant::now();
    for _ in 0..steps {
        for c in data.ctrl_mut().iter_mut().take(nu) {
            *c = rng.random_range(-1.0..1.0);
        }
        for _ in 0..FRAME_SKIP {
            data.step();
        }
    }
    steps as f64 / t.elapsed().as_secs_f64()
}

/// Our environment's random-action step rate on one thread (steps per second).
pub(crate) fn env_rate(robot: Robot, steps: usize) -> f64 {
    let mut env = MujocoEnv::new(robot, &MujocoConfig::default());
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let nu = env.state_sizes().1.min(match env.action_space() {
        jsae_wire::ActionSpace::Continuous { dim, .. } => *dim,
        jsae_wire::ActionSpace::Discrete { .. } => 0,
    });
    let mut action = vec![0.0f32; nu];
    let mut states = jsae_wire::StateBatch::empty(env.state_space());
    env.reset(&mut rng);
    let t = Instant::now();
    for _ in 0..steps {
        action
            .iter_mut()
            .for_each(|a| *a = rng.random_range(-1.0..1.0));
        let step = env.step(ActionRef::Continuous(&action));
        states.clear();
        env.push_state(&mut states);
        if step.terminated || step.truncated {
            env.reset(&mut rng);
        }
    }
    steps as f64 / t.elapsed().as_secs_f64()
}

fn actor_rate(env: EnvName, algo: Algo, envs: usize, threads: usize, steps: usize) -> f64 {
    let mut config = TrainConfig::defaults(env, algo);
    config.step_threads = threads;
    config.embedding.pretrain_transitions = 4_096;
    config.embedding.pretrain_epochs = 2;
    let mut worker = trained_worker(&config, envs, DeviceKind::Flex);
    worker.collect(8);
    let rounds = steps.div_ceil(envs * config.rollout_len).max(1);
    let t = Instant::now();
    for _ in 0..rounds {
        worker.collect(config.rollout_len);
    }
    (rounds * envs * config.rollout_len) as f64 / t.elapsed().as_secs_f64()
}

fn gymnasium_rate(gym_id: &str, steps: usize) -> Result<f64, String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .ok_or("no workspace root")?
        .to_path_buf();
    let setup = Command::new(root.join("scripts/setup-python.sh"))
        .output()
        .map_err(|e| format!("scripts/setup-python.sh: {e}"))?;
    if !setup.status.success() {
        return Err(String::from_utf8_lossy(&setup.stderr).trim().to_string());
    }
    let python = String::from_utf8_lossy(&setup.stdout).trim().to_string();
    let out = Command::new(python)
        .arg(root.join("scripts/python/gymnasium_steprate.py"))
        .args([gym_id, &steps.to_string()])
        .output()
        .map_err(|e| e.to_string())?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).trim().to_string());
    }
    String::from_utf8_lossy(&out.stdout)
        .trim()
        .parse()
        .map_err(|e| format!("{e}"))
}

/// Measures one robot with `envs` environments per actor.
pub fn bench_robot(env: EnvName, envs: usize, quick: bool) -> MujocoRates {
    let (robot, gym_id, steps) = match env {
        EnvName::Ant => (Robot::Ant, "Ant-v5", 20_000),
        _ => (Robot::HalfCheetah, "HalfCheetah-v5", 60_000),
    };
    let steps = if quick { steps / 20 } else { steps };
    MujocoRates {
        raw: raw_rate(robot, steps),
        env_random: env_rate(robot, steps),
        actor_ppo: actor_rate(env, Algo::Ppo, envs, 1, steps),
        actor_jsae: actor_rate(env, Algo::Jsae, envs, 1, steps),
        actor_jsae_cores: actor_rate(env, Algo::Jsae, envs, 0, steps),
        cores: jsae_envs::step_threads(0, 1, false),
        gymnasium: match gymnasium_rate(gym_id, steps) {
            Ok(r) => Some(r),
            Err(e) => {
                eprintln!("bench: Gymnasium rate not measured: {e}");
                None
            }
        },
    }
}

/// Runs both robots and formats the table.
pub fn run(envs: usize, quick: bool) -> String {
    let mut out = format!(
        "MuJoCo env-steps/s (frame_skip 5; actor: {envs} envs, batched inference on flex)\n"
    );
    let rates: Vec<(EnvName, MujocoRates)> = [EnvName::HalfCheetah, EnvName::Ant]
        .into_iter()
        .map(|env| (env, bench_robot(env, envs, quick)))
        .collect();
    let cores = rates.first().map_or(1, |r| r.1.cores);
    out.push_str(&format!(
        "{:<13} {:>9} {:>9} {:>9} {:>9} {:>11} {:>9}\n",
        "env", "(c) raw", "(a) env", "(b) ppo", "(b) jsae", "(b) jsae xN", "(d) gym"
    ));
    for (env, r) in &rates {
        out.push_str(&format!(
            "{:<13} {:>9.0} {:>9.0} {:>9.0} {:>9.0} {:>11.0} {:>9.0}\n",
            env.as_str(),
            r.raw,
            r.env_random,
            r.actor_ppo,
            r.actor_jsae,
            r.actor_jsae_cores,
            r.gymnasium.unwrap_or(f64::NAN)
        ));
    }
    out.push_str(&format!(
        "{:<13} {:>7} {:>7} {:>8} {:>9} {:>9} {:>10}\n",
        "ratios", "a/c", "ppo/c", "jsae/c", "ppo/gym", "jsae/gym", "jsaexN/gym"
    ));
    for (env, r) in &rates {
        let gym = r.gymnasium.unwrap_or(f64::NAN);
        out.push_str(&format!(
            "{:<13} {:>7.2} {:>7.2} {:>8.2} {:>9.2} {:>9.2} {:>10.2}\n",
            env.as_str(),
            r.env_random / r.raw,
            r.actor_ppo / r.raw,
            r.actor_jsae / r.raw,
            r.actor_ppo / gym,
            r.actor_jsae / gym,
            r.actor_jsae_cores / gym,
        ));
    }
    out.push_str(&format!(
        "(c) ctrl + mj_step x5 only, one thread; (a) our env, random actions, one thread; (b) actor rollouts with inference, stepping on one thread (xN: on {cores} threads, one per core); (d) Gymnasium v5, Python, one env, random actions\n"
    ));
    out
}
