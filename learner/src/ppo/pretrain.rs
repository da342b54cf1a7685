//! Pre-training the recommender's categorical policy on logged purchases before it plays
//! (`ppo.logged_pretrain_epochs`): the next-purchase cross-entropy alone over the steps of
//! the sessions the simulator's model is built from (the held-out ones never), through the
//! PPO update's own minibatches, clipping and Adam on the fused path. With no advantages and
//! the entropy and value terms off only the actor moves; PPO then starts with fresh Adam
//! moments, as after a warm start.

use std::time::Instant;

use jsae_envs::Env;
use jsae_envs::recsys::RecommenderEnv;
use jsae_proto::settings::{EnvName, TrainConfig};
use jsae_proto::{ActionBatch, StateBatch, StateSpace};
use ndarray::Array2;
use rand::seq::SliceRandom;

use super::batch::{Batch, NetworkInput};
use super::fused_update::{FusedState, epochs};
use super::{Learner, LearnerError};
use crate::fused::HostPolicy;
use crate::policy::PolicyHead;

/// Logged steps turned into network inputs at a time (their dense one-hots are transient).
const CHUNK: usize = 4096;

/// What pre-training on logged purchases did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PretrainReport {
    /// Logged steps (state, item bought next) trained on.
    pub samples: usize,
    /// Passes over them.
    pub epochs: usize,
    /// Mean next-purchase cross-entropy (nats) over the first epoch's minibatches.
    pub first_epoch_loss: f64,
    /// The same over the last epoch's.
    pub last_epoch_loss: f64,
    /// Wall time.
    pub seconds: f64,
}

impl std::fmt::Display for PretrainReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "policy pre-trained on {} logged purchases, {} epochs in {:.0} s (next-purchase \
             loss {:.3} -> {:.3} nats)",
            self.samples, self.epochs, self.seconds, self.first_epoch_loss, self.last_epoch_loss
        )
    }
}

impl Learner {
    /// Pre-trains on the run's logged purchases when `ppo.logged_pretrain_epochs` asks for
    /// it (the recommender's sessions without the held-out ones, as the environment reads
    /// them); None when it does not.
    ///
    /// # Errors
    /// When the data cannot be read, or as [`Self::pretrain_next_purchase`].
    pub fn pretrain_for_run(
        &mut self,
        config: &TrainConfig,
    ) -> Result<Option<PretrainReport>, LearnerError> {
        if self.config.logged_pretrain_epochs == 0 || config.env != EnvName::Recommender {
            return Ok(None);
        }
        let env = RecommenderEnv::new(&config.environment)
            .map_err(|e| LearnerError::Pretrain(e.to_string()))?;
        let (states, next) = env.logged_steps();
        self.pretrain_next_purchase(&states, env.state_space(), &next)
            .map(Some)
    }

    /// Trains the policy's softmax to predict the item bought next from `states` (of
    /// `space`, as the actors encode them) for `ppo.logged_pretrain_epochs` passes; `next[i]`
    /// is the item bought after `states`' row `i`.
    ///
    /// # Errors
    /// When the policy is not categorical, the states are not of the policy's input width,
    /// the lengths differ, an item is not an action, or there is nothing to train on.
    pub fn pretrain_next_purchase(
        &mut self,
        states: &StateBatch,
        space: &StateSpace,
        next: &[u32],
    ) -> Result<PretrainReport, LearnerError> {
        let started = Instant::now();
        let PolicyHead::Categorical { n } = self.policy.head() else {
            return Err(LearnerError::Pretrain(
                "needs a categorical policy (--algo ppo)".into(),
            ));
        };
        let x_dim = self.policy.input_dim();
        if space.feature_len() != x_dim {
            return Err(LearnerError::Pretrain(format!(
                "states of width {} for a policy input of {x_dim}",
                space.feature_len()
            )));
        }
        if states.len() != next.len() || next.is_empty() {
            return Err(LearnerError::Pretrain(format!(
                "{} states and {} next purchases",
                states.len(),
                next.len()
            )));
        }
        if let Some(bad) = next.iter().find(|&&k| k as usize >= n) {
            return Err(LearnerError::Pretrain(format!(
                "item {bad} is not one of the {n} actions"
            )));
        }
        let batch = logged_batch(states, space, next, self.policy.pair_feature());
        let mut config = self.config.clone();
        config.epochs = 1;
        config.ent_coef = 0.0;
        config.vf_coef = 0.0;
        config.next_purchase_coef = 1.0;
        config.norm_adv = false;
        config.target_kl = None;
        let mut host = HostPolicy::from_policy(&self.policy);
        let mut state = FusedState::new();
        let lr = self.config.logged_pretrain_lr as f32;
        let rng = &mut self.rng;
        let wanted = self.config.logged_pretrain_epochs;
        let losses: Vec<f64> = rayon::scope(|_| {
            let mut order: Vec<usize> = (0..batch.len()).collect();
            (0..wanted)
                .map(|e| {
                    // annealed linearly to 0 over the passes, as PPO's rate over a run
                    let lr = lr * (1.0 - e as f32 / wanted as f32);
                    let m = epochs(
                        &config,
                        &batch,
                        &batch.input,
                        lr,
                        &mut host,
                        &mut state,
                        || {
                            order.shuffle(rng);
                            order.clone()
                        },
                    );
                    m.next_purchase_loss
                })
                .collect()
        });
        self.policy.load_host(&host.params);
        // PPO's own moments start afresh
        self.fused = FusedState::new();
        Ok(PretrainReport {
            samples: batch.len(),
            epochs: losses.len(),
            first_epoch_loss: losses.first().copied().unwrap_or(f64::NAN),
            last_epoch_loss: losses.last().copied().unwrap_or(f64::NAN),
            seconds: started.elapsed().as_secs_f64(),
        })
    }
}

/// A batch of logged steps for the fused update: the states as network inputs (one chunk
/// of dense one-hots at a time), the item bought next as both the action and the
/// next-purchase target, and no advantages, returns or behaviour log-probabilities.
fn logged_batch(
    states: &StateBatch,
    space: &StateSpace,
    next: &[u32],
    pair: Option<jsae_nn::PairCross>,
) -> Batch {
    let x_dim = space.feature_len();
    let rows = states.len();
    let mut input: Option<NetworkInput> = None;
    let (mut chunk, mut dense) = (StateBatch::empty(space), Vec::new());
    for start in (0..rows).step_by(CHUNK) {
        chunk.clear();
        for i in start..(start + CHUNK).min(rows) {
            chunk.push_row_of(states, i);
        }
        chunk.write_features(space, &mut dense);
        let part = NetworkInput::new(&dense, x_dim, None, pair);
        input = Some(match input {
            None => part,
            Some(mut all) => {
                all.append(part);
                all
            }
        });
    }
    let zeros = vec![0.0; rows];
    Batch {
        x_dim,
        x: Vec::new(),
        input: input.unwrap_or_else(|| NetworkInput::Dense(Array2::zeros((0, x_dim)))),
        actions: ActionBatch::Discrete(next.to_vec()),
        logp: zeros.clone(),
        adv: zeros.clone(),
        returns: zeros.clone(),
        values: zeros,
        next_purchase: next.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use jsae_nn::DeviceKind;
    use jsae_proto::{StateBatch, StateSpace};

    use super::super::Learner;
    use crate::PpoConfig;
    use crate::fused::HostPolicy;
    use crate::policy::PolicyHead;

    /// 6 items and "none": the item bought after (a, b) is `(a + 2 b + 1) mod 6`, which no
    /// sum of a score per item and a score per last item gives; a pair feature tells the
    /// pairs apart.
    fn logged() -> (StateBatch, StateSpace, Vec<u32>) {
        let space = StateSpace::Categorical { sizes: vec![7, 7] };
        let (mut data, mut next) = (Vec::new(), Vec::new());
        for _ in 0..20 {
            for a in 0..6 {
                for b in 0..6 {
                    data.extend([a, b]);
                    next.push((a + 2 * b + 1) % 6);
                }
            }
        }
        let states = StateBatch::Categorical { factors: 2, data };
        (states, space, next)
    }

    fn learner(epochs: usize) -> Learner {
        let config = PpoConfig {
            logged_pretrain_epochs: epochs,
            next_purchase_coef: 1.0,
            pair_buckets: 256,
            minibatch_size: 64,
            logged_pretrain_lr: 3e-3,
            ..PpoConfig::default()
        };
        Learner::new(
            config,
            14,
            PolicyHead::Categorical { n: 6 },
            0,
            3,
            DeviceKind::Flex,
        )
    }

    #[test]
    fn pretraining_learns_the_logged_next_purchase_and_leaves_the_critic() {
        let (states, space, next) = logged();
        let mut l = learner(60);
        let critic = HostPolicy::from_policy(l.policy()).params.critic;
        let r = l
            .pretrain_next_purchase(&states, &space, &next)
            .expect("pre-trains");
        assert_eq!((r.samples, r.epochs), (720, 60));
        assert!(
            r.first_epoch_loss > 1.5 && r.last_epoch_loss < 0.1,
            "{} -> {}",
            r.first_epoch_loss,
            r.last_epoch_loss
        );
        assert_eq!(HostPolicy::from_policy(l.policy()).params.critic, critic);
        // the greedy action of every pair is the item bought after it
        let x = states.features(&space);
        let logits = l.policy().head_outputs(&x[..36 * 14]);
        for (row, &t) in logits.chunks_exact(6).zip(&next) {
            let best = (0..6).max_by(|&i, &j| row[i].total_cmp(&row[j]));
            assert_eq!(best, Some(t as usize), "{row:?}");
        }
    }

    #[test]
    fn pretraining_refuses_what_it_does_not_fit() {
        let (states, space, next) = logged();
        let mut l = learner(1);
        let mut bad = next.clone();
        bad[3] = 6;
        for (s, n) in [(&space, &next[1..]), (&space, &bad[..])] {
            let e = l
                .pretrain_next_purchase(&states, s, n)
                .expect_err("refused");
            assert!(e.to_string().contains("logged purchases"), "{e}");
        }
        let narrow = StateSpace::Categorical { sizes: vec![7] };
        assert!(l.pretrain_next_purchase(&states, &narrow, &next).is_err());
        let mut gaussian = Learner::new(
            PpoConfig::default(),
            14,
            PolicyHead::Gaussian { dim: 2 },
            0,
            3,
            DeviceKind::Flex,
        );
        let e = gaussian
            .pretrain_next_purchase(&states, &space, &next)
            .expect_err("not categorical");
        assert!(e.to_string().contains("categorical"), "{e}");
    }
}
