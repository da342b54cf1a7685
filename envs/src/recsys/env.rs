//! The recommender as an environment: the state is the last `history` purchases (slot
//! `top_n` for "none" at the start), the action the recommended item; the user's next
//! purchase is drawn from the n-gram model with the recommendation boosted. Episodes last
//! `episode_len` purchases and end truncated (the user would go on buying).

use std::sync::Arc;

use jsae_env_spec::{EnvName, RecommenderConfig};
use jsae_spaces::{ActionSpace, StateBatch, StateSpace};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::RecsysError;
use super::model_handle::{ModelHandle, model_handle};
use super::ngram::NgramModel;
use crate::{ActionRef, Env, EnvConfig, Step};

/// The recommender environment.
#[derive(Debug)]
pub struct RecommenderEnv {
    handle: Arc<ModelHandle>,
    model: Arc<NgramModel>,
    states: StateSpace,
    actions: ActionSpace,
    history: Vec<u32>,
    steps: u32,
    episode_len: u32,
    rng: ChaCha8Rng,
}

impl RecommenderEnv {
    /// An environment over the process's model for these settings.
    pub fn new(config: &EnvConfig) -> Result<Self, RecsysError> {
        let r: &RecommenderConfig = &config.recommender;
        let handle = model_handle(r)?;
        let (states, actions) = EnvName::Recommender.spaces(config);
        let model = handle.current();
        Ok(Self {
            history: vec![model.catalogue().none(); r.history as usize],
            model,
            handle,
            states,
            actions,
            steps: 0,
            episode_len: r.episode_len,
            rng: ChaCha8Rng::seed_from_u64(0),
        })
    }

    /// The model in use this episode.
    pub fn model(&self) -> &NgramModel {
        &self.model
    }

    /// The logged purchases the model is built from, as this environment's states and the
    /// item bought in each ([`ModelHandle::logged_steps`]): what a policy can learn from
    /// before it plays.
    pub fn logged_steps(&self) -> (StateBatch, Vec<u32>) {
        self.handle.logged_steps(self.history.len())
    }

    /// The state: the last purchases, oldest first.
    pub fn history(&self) -> &[u32] {
        &self.history
    }
}

impl Env for RecommenderEnv {
    fn state_space(&self) -> &StateSpace {
        &self.states
    }

    fn action_space(&self) -> &ActionSpace {
        &self.actions
    }

    fn has_success(&self) -> bool {
        false
    }

    fn reset(&mut self, rng: &mut ChaCha8Rng) {
        // a model rebuilt from new sessions takes effect from the next episode
        self.model = self.handle.current();
        self.rng = ChaCha8Rng::seed_from_u64(rng.random());
        let none = self.model.catalogue().none();
        self.history.fill(none);
        let first = self.model.sample_start(&mut self.rng);
        if let Some(last) = self.history.last_mut() {
            *last = first;
        }
        self.steps = 0;
    }

    fn step(&mut self, action: ActionRef<'_>) -> Step {
        let rec = match action {
            ActionRef::Discrete(a) => a,
            ActionRef::Continuous(_) => u32::MAX,
        };
        let n = self.history.len();
        let (before, last) = (self.history[n - 2], self.history[n - 1]);
        let bought = self.model.sample_next(before, last, rec, &mut self.rng);
        self.history.rotate_left(1);
        self.history[n - 1] = bought;
        self.steps += 1;
        Step {
            reward: self.model.reward(rec, bought),
            terminated: false,
            truncated: self.steps >= self.episode_len,
            success: false,
        }
    }

    fn push_state(&self, out: &mut StateBatch) {
        if let StateBatch::Categorical { data, .. } = out {
            data.extend_from_slice(&self.history);
        }
    }
}
