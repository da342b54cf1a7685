//! Settings of the embedding model and its training.

use serde::{Deserialize, Serialize};

use jsae_spaces::{ActionSpace, StateSpace};

use super::embedding_recommender::RecommenderEmbeddingConfig;

/// Most negatives a sampled-softmax minibatch draws (`embedding.negatives`).
pub const MAX_NEGATIVES: usize = 1 << 16;

/// Embedding model and trainer settings (paper section 4.3 and appendix; public reference
/// code for the rest). The defaults are the gridworld's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EmbeddingConfig {
    /// Width `m` of a state embedding `x`.
    pub state_dim: usize,
    /// Width `d` of an action embedding `e`.
    pub action_dim: usize,
    /// Adam learning rate of phi, g, T and f.
    pub lr: f64,
    /// Weight decay of phi, g, T and f.
    pub weight_decay: f32,
    /// Decoupled weight decay (AdamW). With Adam's L2 decay (`false`, the reference code's
    /// choice) a table row that gets no gradient, such as an unvisited state's phi(s), is
    /// pushed to 0 at a full learning-rate step per update, so every state random play never
    /// reached ends up with the same embedding.
    pub decoupled_weight_decay: bool,
    /// Transitions per minibatch.
    pub batch_size: usize,
    /// Uniformly random transitions collected before pre-training, at least (see
    /// `pretrain_per_action`). 3,000 gives the gridworld's 512 action embeddings no
    /// structure; 20,000 does.
    pub pretrain_transitions: usize,
    /// With discrete actions, pre-training also waits for this many random transitions per
    /// action: the budget is `max(pretrain_transitions, pretrain_per_action x actions)`
    /// ([`EmbeddingConfig::pretrain_budget`]), so it grows with the action space (0: exactly
    /// `pretrain_transitions`). At 4,096 gridworld actions 20,000 transitions (5 per action)
    /// left JSAE at success 0 on 3 of 3 seeds; 25 per action solves it (docs/src/experiments/large-action-spaces.md).
    /// Not at catalogue scale (`sampled_softmax_from`), where the budget is
    /// `pretrain_transitions`.
    pub pretrain_per_action: usize,
    /// Passes over the pre-training transitions.
    pub pretrain_epochs: usize,
    /// Hidden width of a tanh layer in T (0: T is one linear layer on `concat(x, e)`, as in the
    /// paper's gridworld; the slotmachine's next reel position is `position + advance mod 6`,
    /// which no linear function of the two embeddings can express).
    pub transition_hidden: usize,
    /// Hidden width of the continuous-action decoder f.
    pub decoder_hidden: usize,
    /// Discrete actions from which f searches an approximate nearest-neighbour index (an
    /// HNSW graph whose search width is calibrated to recall@10 0.96 against the exact scan
    /// when an embedding version arrives) instead of scanning every action (0: always scan).
    /// The exact scan of 100,000 actions takes about 2 ms a lookup on one core, the index
    /// 0.09 ms (`jsae bench --catalogue`).
    pub approx_nearest_from: usize,
    /// Discrete actions from which the model trains at catalogue scale (0: never): T predicts
    /// the next state's last factor only (in the recommender the others are the state's own
    /// items, shifted) and, like the next-item head, by a sampled softmax over the item bought
    /// and `negatives` items drawn per minibatch, with the sampling-probability (logQ)
    /// correction; phi's and g's tables and T's output rows live on the host and take lazy
    /// Adam steps in the rows a minibatch touches. A dense softmax over 1M items at a
    /// minibatch of 4,096 is 16 GB of logits. Snapshots carry no T (acting never reads it).
    pub sampled_softmax_from: usize,
    /// Items drawn per minibatch as the sampled softmax's negatives (shared by its rows).
    pub negatives: usize,
    /// Transitions the replay buffer keeps (oldest dropped first).
    pub replay_capacity: usize,
    /// Continuous updates: new transitions between two updates (0 turns them off).
    pub update_every: usize,
    /// Continuous updates: minibatch steps per update (each publishes a new version).
    pub update_steps: usize,
    /// Continuous updates: learning rate (usually below the pre-training one).
    pub update_lr: f64,
    /// Real-valued states: phi sees them normalised by running mean and variance (part of
    /// the embedding's weights and snapshots), and T predicts normalised next states.
    pub normalize_states: bool,
    /// The share of the run's env steps from which the embedding no longer changes: the
    /// learner asks the embedder to hold it (`Embedder.HoldEmbedding`), so the policy's last
    /// updates and its evaluation use one embedding (None, the default: never;
    /// docs/src/experiments/greedy-loops.md has what it changed on the gridworld).
    pub hold_from: Option<f64>,
    /// The recommender's item-structure settings (`[embedding.recommender]`).
    pub recommender: RecommenderEmbeddingConfig,
}

impl Default for EmbeddingConfig {
    fn default() -> Self {
        Self {
            state_dim: 8,
            action_dim: 2,
            lr: 0.01,
            weight_decay: 1e-4,
            decoupled_weight_decay: true,
            batch_size: 512,
            pretrain_transitions: 20_000,
            pretrain_per_action: 25,
            pretrain_epochs: 30,
            transition_hidden: 0,
            decoder_hidden: 64,
            approx_nearest_from: 50_000,
            sampled_softmax_from: 50_000,
            negatives: 1024,
            replay_capacity: 200_000,
            update_every: 20_480,
            update_steps: 50,
            update_lr: 0.003,
            normalize_states: false,
            hold_from: None,
            recommender: RecommenderEmbeddingConfig::default(),
        }
    }
}

impl EmbeddingConfig {
    /// Random transitions pre-training waits for with these actions: at least
    /// `pretrain_transitions`, and `pretrain_per_action` per discrete action.
    pub fn pretrain_budget(&self, states: &StateSpace, actions: &ActionSpace) -> usize {
        // at catalogue scale the items learn from what follows each purchase (the sampled
        // next-item and T losses over every transition), not from each being tried: 25
        // tries of each of a million items would be 25M random steps before any learning
        if self.samples_items(states, actions) {
            return self.pretrain_transitions;
        }
        let per_action = actions
            .num_discrete()
            .map_or(0, |n| n.saturating_mul(self.pretrain_per_action));
        self.pretrain_transitions.max(per_action)
    }

    /// Whether a model of these spaces trains at catalogue scale (`sampled_softmax_from`):
    /// that many discrete actions or more, and categorical states whose last factor is an
    /// action or none (`n + 1` values: the recommender's item bought last), which is what T
    /// predicts there.
    pub fn samples_items(&self, states: &StateSpace, actions: &ActionSpace) -> bool {
        let (Some(n), StateSpace::Categorical { sizes }) = (actions.num_discrete(), states) else {
            return false;
        };
        self.sampled_softmax_from > 0
            && n >= self.sampled_softmax_from
            && sizes.last() == Some(&(n + 1))
    }

    /// Width of the policy's input: `x = phi(s)`, followed by the next-item head's output
    /// where the model has one (`embedding.recommender.next_item_coef`).
    pub fn policy_input_dim(&self) -> usize {
        self.state_dim
            + if self.recommender.next_item() {
                self.action_dim
            } else {
                0
            }
    }

    /// Checks the settings; the reason names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        self.recommender.validate(self.state_dim)?;
        if let Some(share) = self.hold_from
            && !(share > 0.0 && share <= 1.0)
        {
            return Err(format!(
                "embedding.hold_from must be in (0, 1], got {share}"
            ));
        }
        if self.state_dim == 0 || self.action_dim == 0 {
            return Err("embedding.state_dim and embedding.action_dim must be positive".into());
        }
        use super::ppo::MAX_WIDTH;
        for (key, v) in [
            ("state_dim", self.state_dim),
            ("action_dim", self.action_dim),
            ("transition_hidden", self.transition_hidden),
            ("decoder_hidden", self.decoder_hidden),
        ] {
            if v > MAX_WIDTH {
                return Err(format!("embedding.{key} is {v}, at most {MAX_WIDTH}"));
            }
        }
        if !(1..=MAX_NEGATIVES).contains(&self.negatives) {
            return Err(format!(
                "embedding.negatives is {}, it must be in 1..={MAX_NEGATIVES}",
                self.negatives
            ));
        }
        let positive = |v: f64| v > 0.0 && v.is_finite();
        if !positive(self.lr) || !positive(self.update_lr) {
            return Err("embedding.lr and embedding.update_lr must be positive".into());
        }
        if self.batch_size == 0 || self.pretrain_transitions == 0 || self.pretrain_epochs == 0 {
            return Err(
                "embedding.batch_size, pretrain_transitions and pretrain_epochs must be positive"
                    .into(),
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Algo, EnvName};

    #[test]
    fn the_pretraining_budget_grows_with_the_actions() {
        let c = EmbeddingConfig::default();
        let discrete = |n| ActionSpace::Discrete { n };
        assert_eq!(
            c.pretrain_budget(&StateSpace::discrete(10), &discrete(512)),
            20_000
        );
        assert_eq!(
            c.pretrain_budget(&StateSpace::discrete(10), &discrete(4096)),
            102_400
        );
        let continuous = ActionSpace::Continuous {
            dim: 2,
            low: vec![-1.0; 2],
            high: vec![1.0; 2],
        };
        assert_eq!(
            c.pretrain_budget(&StateSpace::discrete(10), &continuous),
            20_000
        );
        let fixed = EmbeddingConfig {
            pretrain_per_action: 0,
            ..c
        };
        assert_eq!(
            fixed.pretrain_budget(&StateSpace::discrete(10), &discrete(4096)),
            20_000
        );
    }

    #[test]
    fn the_hold_is_a_share_of_the_run() {
        let c = EmbeddingConfig::default();
        assert_eq!(c.hold_from, None);
        let set = EmbeddingConfig {
            hold_from: Some(0.7),
            ..c.clone()
        };
        set.validate().expect("valid");
        let mut run = crate::TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
        run.env_steps = 500_000;
        assert!(!run.embedding_held_at(500_000), "unset: never");
        run.embedding.hold_from = Some(0.7);
        assert!(!run.embedding_held_at(349_999));
        assert!(run.embedding_held_at(350_000));
        run.algo = Algo::Ppo;
        assert!(!run.embedding_held_at(500_000), "no embedder to hold");
        for bad in [0.0, 1.5, f64::NAN] {
            let bad = EmbeddingConfig {
                hold_from: Some(bad),
                ..c.clone()
            };
            let reason = bad.validate().expect_err("out of range");
            assert!(reason.contains("embedding.hold_from"), "{reason}");
        }
    }
}
