//! The recommender as an environment: the state is the last `history` purchases (slot
//! `top_n` for "none" at the start), the action the recommended item; the user's next
//! purchase is drawn from the n-gram model with the recommendation boosted. Episodes start
//! as the settings' `start` says (a data session's first purchase, or two uniformly random
//! items as in the authors' environment), last `episode_len` purchases and end truncated
//! (the user would go on buying), unless the user leaves after a recommendation they did
//! not buy (`leave_on_miss` times its value, the long-horizon option): that ends it
//! terminated.

use std::sync::Arc;

use jsae_env_spec::{EnvName, RecommenderConfig, StartRule};
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
    start: StartRule,
    leave_on_miss: f64,
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
            start: r.start,
            leave_on_miss: r.leave_on_miss,
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

    /// The probability that the user leaves after not buying the recommended `item`.
    pub fn leave_probability(&self, item: u32) -> f64 {
        (self.leave_on_miss * self.model.value(item)).min(1.0)
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
        let n = self.history.len();
        match self.start {
            StartRule::Session => self.history[n - 1] = self.model.sample_start(&mut self.rng),
            StartRule::UniformPair => {
                for slot in &mut self.history[n - 2..] {
                    *slot = self.model.sample_uniform(&mut self.rng);
                }
            }
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
        // drawn only where users may leave: the default's episodes stay as they were
        let leaves = self.leave_on_miss > 0.0
            && bought != rec
            && self.rng.random::<f64>() < self.leave_probability(rec);
        Step {
            reward: self.model.reward(rec, bought),
            terminated: leaves,
            truncated: !leaves && self.steps >= self.episode_len,
            success: false,
            lost: false,
        }
    }

    fn push_state(&self, out: &mut StateBatch) {
        if let StateBatch::Categorical { data, .. } = out {
            data.extend_from_slice(&self.history);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_env_spec::SessionSource;

    fn env(edit: impl FnOnce(&mut RecommenderConfig)) -> RecommenderEnv {
        let mut config = EnvConfig::default();
        let r = &mut config.recommender;
        r.source = SessionSource::Synthetic;
        r.top_n = 40;
        r.synthetic.items = 40;
        r.synthetic.sessions = 400;
        edit(r);
        RecommenderEnv::new(&config).expect("builds")
    }

    #[test]
    fn uniform_pair_starts_fill_both_slots_and_session_starts_one() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut session = env(|_| {});
        let none = session.model().catalogue().none();
        session.reset(&mut rng);
        assert_eq!(session.history()[0], none);
        let mut pair = env(|r| r.start = StartRule::UniformPair);
        let mut firsts = std::collections::HashSet::new();
        for _ in 0..200 {
            pair.reset(&mut rng);
            assert!(
                pair.history().iter().all(|&i| i < 40),
                "{:?}",
                pair.history()
            );
            firsts.insert(pair.history()[0]);
        }
        assert!(
            firsts.len() > 30,
            "uniform over the catalogue: {}",
            firsts.len()
        );
    }

    #[test]
    fn users_who_leave_end_the_episode_terminated_and_only_after_a_miss() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut leaving = env(|r| r.leave_on_miss = 1.0);
        let (mut episodes, mut steps) = (0, 0);
        while episodes < 50 {
            leaving.reset(&mut rng);
            episodes += 1;
            loop {
                let step = leaving.step(ActionRef::Discrete(3));
                let bought = *leaving.history().last().expect("history");
                steps += 1;
                assert!(!(step.terminated && step.truncated));
                assert_eq!(
                    step.terminated,
                    bought != 3,
                    "a miss ends it, a sale does not"
                );
                if step.terminated || step.truncated {
                    break;
                }
            }
        }
        assert!(steps < 50 * 20, "{steps}");
        // the default never terminates and its purchases do not draw for leaving
        let (mut a, mut b) = (env(|_| {}), env(|r| r.leave_on_miss = 0.0));
        let (mut ra, mut rb) = (ChaCha8Rng::seed_from_u64(3), ChaCha8Rng::seed_from_u64(3));
        a.reset(&mut ra);
        b.reset(&mut rb);
        for t in 1..=20 {
            let (x, y) = (
                a.step(ActionRef::Discrete(1)),
                b.step(ActionRef::Discrete(1)),
            );
            assert!(!x.terminated && x.truncated == (t == 20));
            assert_eq!((x.reward, a.history()), (y.reward, b.history()));
        }
    }
}
