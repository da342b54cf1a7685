//! Environments behind one trait, with Gymnasium's step semantics: `terminated` (a terminal
//! state was reached: value 0 after it) and `truncated` (the time limit cut the episode: the
//! next state still has a value) are separate.
//!
//! Layout: the [`Env`] trait, [`make_env`] and vectorised stepping ([`step_all`]) here;
//! `gridworld` (continuous and discrete, with `geometry` for its walls), `slotmachine`,
//! `mujoco` (HalfCheetah and Ant, equal to Gymnasium v5), and `recsys` (the recommender's
//! sessions, session store, n-gram MDP and environment). Depends on `jsae-spaces` and `jsae-env-spec` only (no networking, no models).

// One unsafe call (MuJoCo's global log configuration, mujoco.rs) is allowed locally.
#![deny(unsafe_code)]

mod geometry;
pub mod gridworld;
pub mod mujoco;
mod pool;
pub mod recsys;
pub mod slotmachine;

use jsae_spaces::ActionBatch;

pub use crate::recsys::{RecommenderEnv, RecsysError};
pub use gridworld::Gridworld;
pub use jsae_env_api::{ActionRef, Env, Step};
pub use jsae_env_spec::{
    EnvConfig, EnvName, GridworldConfig, GymConfig, GymSpace, MujocoConfig, SlotmachineConfig,
    validate_env_config,
};
pub use mujoco::{MujocoEnv, Robot};
pub use pool::{EnvPool, LocalEnvs};
pub use slotmachine::Slotmachine;

/// Steps `envs[i]` with row `i` of `actions` into `out[i]`, on up to `threads` threads
/// (contiguous chunks of environments: the first on the calling thread, the others on
/// scoped threads; 1: all on the calling thread). Environments own
/// their state, so the result does not depend on `threads`.
pub fn step_all(
    envs: &mut [Box<dyn Env>],
    actions: &ActionBatch,
    out: &mut [Step],
    threads: usize,
) {
    let step_one = |env: &mut Box<dyn Env>, i: usize| env.step(ActionRef::row(actions, i));
    let threads = threads.clamp(1, envs.len().max(1));
    if threads == 1 {
        for (i, (env, o)) in envs.iter_mut().zip(out.iter_mut()).enumerate() {
            *o = step_one(env, i);
        }
        return;
    }
    let chunk = envs.len().div_ceil(threads);
    let step_chunk = |c: usize, envs: &mut [Box<dyn Env>], out: &mut [Step]| {
        for (j, (env, o)) in envs.iter_mut().zip(out.iter_mut()).enumerate() {
            *o = step_one(env, c * chunk + j);
        }
    };
    std::thread::scope(|scope| {
        let mut chunks = envs
            .chunks_mut(chunk)
            .zip(out.chunks_mut(chunk))
            .enumerate();
        // the calling thread steps the first chunk itself: one spawn fewer per step
        let first = chunks.next();
        for (c, (envs, out)) in chunks {
            scope.spawn(move || step_chunk(c, envs, out));
        }
        if let Some((c, (envs, out))) = first {
            step_chunk(c, envs, out);
        }
    });
}

/// Threads for `step_all`: `configured`, or when 0 the machine's cores shared among the
/// `actors` of a run that start on it together, less one core for the learner's update when
/// it runs `beside` them in its own process (at least one each): on 2 cores one actor steps
/// on one thread while the learner updates on the other, and 8 actors on 16 cores step on
/// one thread each, not on 16 each that take turns.
pub fn step_threads(configured: usize, actors: usize, beside: bool) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    match configured {
        0 => (cores.saturating_sub(usize::from(beside)) / actors.max(1)).max(1),
        n => n,
    }
}

/// Why an environment could not be built here.
#[derive(Debug, thiserror::Error)]
pub enum MakeEnvError {
    /// The recommender's data.
    #[error(transparent)]
    Recsys(#[from] RecsysError),
    /// A gym environment steps in Python workers, through an actor's environment host.
    #[error("gym:{0} steps in Python worker processes connected to an actor, not in this process")]
    Remote(String),
}

/// Builds the named environment (the recommender can fail: it reads its data; a gym
/// environment is not built here).
pub fn make_env(name: EnvName, config: &EnvConfig) -> Result<Box<dyn Env>, MakeEnvError> {
    Ok(match name {
        EnvName::Gridworld => Box::new(Gridworld::new(config.gridworld.clone(), false)),
        EnvName::GridworldDiscrete => Box::new(Gridworld::new(config.gridworld.clone(), true)),
        EnvName::Slotmachine => Box::new(Slotmachine::new(config.slotmachine.clone())),
        EnvName::HalfCheetah => Box::new(MujocoEnv::new(Robot::HalfCheetah, &config.mujoco)),
        EnvName::Ant => Box::new(MujocoEnv::new(Robot::Ant, &config.mujoco)),
        EnvName::Recommender => Box::new(RecommenderEnv::new(config)?),
        EnvName::Corridor => Box::new(jsae_env_example::Corridor::new(config.corridor.clone())),
        EnvName::Gym => return Err(MakeEnvError::Remote(config.gym.id.clone())),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_spaces::StateBatch;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_settings_give_the_spaces_the_environments_have() {
        let mut config = EnvConfig::default();
        config.gridworld.actuators = 5;
        config.gridworld.bins = 7;
        config.slotmachine.bins = 3;
        config.recommender.source = jsae_env_spec::SessionSource::Synthetic;
        config.recommender.top_n = 50;
        config.recommender.history = 3;
        for factored in [false, true] {
            config.slotmachine.factored = factored;
            for name in [
                EnvName::Gridworld,
                EnvName::GridworldDiscrete,
                EnvName::Slotmachine,
                EnvName::HalfCheetah,
                EnvName::Ant,
                EnvName::Recommender,
                EnvName::Corridor,
            ] {
                let env = make_env(name, &config).expect("builds");
                let (states, actions) = name.spaces(&config);
                assert_eq!(
                    (&states, &actions),
                    (env.state_space(), env.action_space()),
                    "{}",
                    name.as_str()
                );
            }
        }
    }

    #[test]
    fn stepping_on_threads_gives_what_one_thread_gives() {
        use rand::{Rng, SeedableRng};
        let config = EnvConfig::default();
        let run = |threads: usize| {
            let mut rng = ChaCha8Rng::seed_from_u64(7);
            let mut envs: Vec<Box<dyn Env>> = (0..5)
                .map(|_| make_env(EnvName::HalfCheetah, &config).expect("builds"))
                .collect();
            for env in &mut envs {
                env.reset(&mut rng);
            }
            let mut steps = vec![Step::default(); envs.len()];
            let mut seen = Vec::new();
            for _ in 0..20 {
                let data = (0..envs.len() * 6)
                    .map(|_| rng.random_range(-1.5f32..1.5))
                    .collect();
                let actions = ActionBatch::Continuous { dim: 6, data };
                step_all(&mut envs, &actions, &mut steps, threads);
                let mut states = StateBatch::empty(envs[0].state_space());
                for env in &envs {
                    env.push_state(&mut states);
                }
                seen.push((steps.clone(), states));
            }
            seen
        };
        let one = run(1);
        for threads in [2, 3, 8] {
            assert!(run(threads) == one, "{threads} threads differ from one");
        }
    }
}
