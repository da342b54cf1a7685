//! An actor's environments as one pool ([`EnvPool`]): `len()` environments stepped together
//! in rollouts and one more, numbered `len()`, for evaluation episodes. [`LocalEnvs`] holds
//! built-in environments in this process; a pool of remote environments (Python workers
//! over gRPC, `jsae-remote-envs`) answers the same calls, so the actor's code does not know
//! where its environments run.

use jsae_spaces::{ActionBatch, ActionSpace, StateBatch, StateSpace};
use rand_chacha::ChaCha8Rng;

use crate::{ActionRef, Env, Step, step_all};

/// An actor's environments.
pub trait EnvPool: Send {
    /// The environments rollouts step (numbered from 0); number `len()` is the evaluation's.
    fn len(&self) -> usize;
    /// Whether no environment is stepped in rollouts.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The state space.
    fn state_space(&self) -> &StateSpace;
    /// The action space.
    fn action_space(&self) -> &ActionSpace;
    /// Whether episodes have a success notion.
    fn has_success(&self) -> bool;
    /// Starts a new episode of environment `i` (any randomness from `rng`).
    fn reset(&mut self, i: usize, rng: &mut ChaCha8Rng);
    /// Steps environments `0..out.len()`, environment `i` with row `i` of `actions`.
    fn step(&mut self, actions: &ActionBatch, out: &mut [Step]);
    /// Steps environment `i` alone (the evaluation's).
    fn step_one(&mut self, i: usize, action: ActionRef<'_>) -> Step;
    /// Appends environment `i`'s current state to `out`.
    fn push_state(&self, i: usize, out: &mut StateBatch);
    /// Why no environment can step any more (remote workers that will not run again); the
    /// actor then stops with this reason. None while the pool can step.
    fn failure(&self) -> Option<String> {
        None
    }
}

/// Built-in environments in this process, stepped on up to `threads` threads.
pub struct LocalEnvs {
    /// `len + 1` environments: the last is the evaluation's.
    envs: Vec<Box<dyn Env>>,
    threads: usize,
}

impl std::fmt::Debug for LocalEnvs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LocalEnvs")
            .field("envs", &self.envs.len())
            .field("threads", &self.threads)
            .finish()
    }
}

impl LocalEnvs {
    /// A pool of `envs` (the last one for evaluation episodes; at least two), stepped on
    /// `threads` threads.
    pub fn new(envs: Vec<Box<dyn Env>>, threads: usize) -> Self {
        assert!(
            envs.len() >= 2,
            "a pool needs an environment and the evaluation's"
        );
        Self { envs, threads }
    }
}

impl EnvPool for LocalEnvs {
    fn len(&self) -> usize {
        self.envs.len() - 1
    }

    fn state_space(&self) -> &StateSpace {
        self.envs[0].state_space()
    }

    fn action_space(&self) -> &ActionSpace {
        self.envs[0].action_space()
    }

    fn has_success(&self) -> bool {
        self.envs[0].has_success()
    }

    fn reset(&mut self, i: usize, rng: &mut ChaCha8Rng) {
        self.envs[i].reset(rng);
    }

    fn step(&mut self, actions: &ActionBatch, out: &mut [Step]) {
        let k = out.len();
        step_all(&mut self.envs[..k], actions, out, self.threads);
    }

    fn step_one(&mut self, i: usize, action: ActionRef<'_>) -> Step {
        self.envs[i].step(action)
    }

    fn push_state(&self, i: usize, out: &mut StateBatch) {
        self.envs[i].push_state(out);
    }
}
