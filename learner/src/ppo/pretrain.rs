//! Readying the recommender's categorical policy from logged purchases before it plays: the
//! count prior its logits add (`ppo.recommender.logged_prior`, [`jsae_agent::prior`]) and pre-training
//! (`ppo.recommender.logged_pretrain_epochs`): the next-purchase cross-entropy alone over the steps of
//! the sessions the simulator's model is built from (the held-out ones never), through the
//! PPO update's own minibatches, clipping and Adam on the fused path. With no advantages and
//! the entropy and value terms off only the actor moves; PPO then starts with fresh Adam
//! moments, as after a warm start.

use std::time::Instant;

use jsae_wire::{ActionBatch, StateBatch, StateSpace};
use ndarray::Array2;
use rand::seq::SliceRandom;

use super::batch::{Batch, NetworkInput};
use super::fused_update::{FusedState, epochs};
use super::{Learner, LearnerError};
use crate::fused::HostPolicy;
use jsae_agent::{CountPrior, PolicyHead};

/// Logged purchases a fresh policy can learn from before it plays (the recommender's
/// sessions without the held-out ones, as the environment reads them; the caller, which
/// knows the data, supplies them).
#[derive(Debug, Clone)]
pub struct LoggedPurchases {
    /// The state before each purchase, as the actors encode states.
    pub states: StateBatch,
    /// Their space.
    pub space: StateSpace,
    /// The item bought after each state.
    pub next: Vec<u32>,
}

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
    /// Whether the settings ask for logged purchases (`ppo.recommender.logged_prior`,
    /// `ppo.recommender.logged_pretrain_epochs`).
    pub fn wants_logs(&self) -> bool {
        self.config.wants_logs()
    }

    /// Readies a fresh policy from `logged` as the settings ask: counts the prior its logits
    /// add, then pre-trains; a line for each, to report.
    ///
    /// # Errors
    /// When the settings ask and there are no logs, or as [`Self::count_prior`] and
    /// [`Self::pretrain_next_purchase`].
    pub fn learn_from_logs(
        &mut self,
        logged: Option<&LoggedPurchases>,
    ) -> Result<Vec<String>, LearnerError> {
        if !self.wants_logs() {
            return Ok(Vec::new());
        }
        let logged = logged.ok_or_else(|| {
            LearnerError::Pretrain(
                "ppo.recommender.logged_prior and ppo.recommender.logged_pretrain_epochs need logged purchases (the \
                 recommender's data)"
                    .into(),
            )
        })?;
        let mut notes = Vec::new();
        if self.config.recommender.logged_prior {
            let contexts = self.count_prior(&logged.states, &logged.space, &logged.next)?;
            notes.push(format!(
                "policy prior counted from {} logged purchases ({contexts} item pairs)",
                logged.next.len()
            ));
        }
        if self.config.recommender.logged_pretrain_epochs > 0 {
            let r = self.pretrain_next_purchase(&logged.states, &logged.space, &logged.next)?;
            notes.push(r.to_string());
        }
        Ok(notes)
    }

    /// Counts the prior the policy's logits add from `states` (of `space`) and the item
    /// bought after each; returns how many item pairs it holds.
    ///
    /// # Errors
    /// As [`Self::pretrain_next_purchase`] for inputs that do not fit the policy.
    pub fn count_prior(
        &mut self,
        states: &StateBatch,
        space: &StateSpace,
        next: &[u32],
    ) -> Result<usize, LearnerError> {
        if !self.config.recommender.logged_prior {
            return Err(LearnerError::Pretrain(
                "ppo.recommender.logged_prior is off".into(),
            ));
        }
        let n = self.check_logged(states, space, next)?;
        let x_dim = space.feature_len();
        let mut rows: Vec<(Vec<u32>, u32)> = Vec::with_capacity(next.len());
        feature_chunks(states, space, |start, dense| {
            for (row, &k) in dense.chunks_exact(x_dim).zip(&next[start..]) {
                let cols = row.iter().enumerate().filter(|(_, v)| **v != 0.0);
                rows.push((cols.map(|(j, _)| j as u32).collect(), k));
            }
        });
        let prior = CountPrior::count(x_dim, n, rows.iter().map(|(c, k)| (c.as_slice(), *k)));
        let contexts = prior.contexts();
        self.prior.set(prior, &self.policy);
        Ok(contexts)
    }

    /// Trains the policy's softmax to predict the item bought next from `states` (of
    /// `space`, as the actors encode them) for `ppo.recommender.logged_pretrain_epochs` passes; `next[i]`
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
        self.check_logged(states, space, next)?;
        let batch = logged_batch(states, space, next, self.policy.pair_feature());
        let mut config = self.config.clone();
        config.epochs = 1;
        config.ent_coef = 0.0;
        config.vf_coef = 0.0;
        config.recommender.next_purchase_coef = 1.0;
        config.norm_adv = false;
        config.target_kl = None;
        let mut host = HostPolicy::from_policy(&self.policy, self.prior.shared());
        let mut state = FusedState::new();
        let lr = self.config.recommender.logged_pretrain_lr as f32;
        let rng = &mut self.rng;
        let wanted = self.config.recommender.logged_pretrain_epochs;
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
        host.params.write_into(&mut self.policy);
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

    /// The actions, when `states` (of `space`) and `next` fit the categorical policy.
    fn check_logged(
        &self,
        states: &StateBatch,
        space: &StateSpace,
        next: &[u32],
    ) -> Result<usize, LearnerError> {
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
        Ok(n)
    }
}

/// `f(first row, their dense features)` for each chunk of `CHUNK` rows of `states` in turn
/// (the whole one-hot matrix is never held at once).
fn feature_chunks(states: &StateBatch, space: &StateSpace, mut f: impl FnMut(usize, &[f32])) {
    let (mut chunk, mut dense) = (StateBatch::empty(space), Vec::new());
    for start in (0..states.len()).step_by(CHUNK) {
        chunk.clear();
        for i in start..(start + CHUNK).min(states.len()) {
            chunk.push_row_of(states, i);
        }
        chunk.write_features(space, &mut dense);
        f(start, &dense);
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
    feature_chunks(states, space, |_, dense| {
        let part = NetworkInput::new(dense, x_dim, None, pair);
        input = Some(match input.take() {
            None => part,
            Some(mut all) => {
                all.append(part);
                all
            }
        });
    });
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
    use jsae_wire::{StateBatch, StateSpace};

    use super::super::Learner;
    use crate::PpoConfig;
    use crate::fused::HostPolicy;
    use jsae_agent::PolicyHead;
    use jsae_settings::RecommenderPpoConfig;

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
            minibatch_size: 64,
            recommender: RecommenderPpoConfig {
                logged_pretrain_epochs: epochs,
                next_purchase_coef: 1.0,
                pair_buckets: 256,
                logged_pretrain_lr: 3e-3,
                ..RecommenderPpoConfig::default()
            },
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
        let critic = l.host_policy().params.critic;
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
        assert_eq!(l.host_policy().params.critic, critic);
        // the greedy action of every pair is the item bought after it
        let x = states.features(&space);
        let logits = l.policy().head_outputs(&x[..36 * 14], l.prior());
        for (row, &t) in logits.chunks_exact(6).zip(&next) {
            let best = (0..6).max_by(|&i, &j| row[i].total_cmp(&row[j]));
            assert_eq!(best, Some(t as usize), "{row:?}");
        }
    }

    #[test]
    fn the_prior_picks_the_counted_item_travels_in_the_bytes_and_is_what_the_update_reads() {
        use jsae_nn::HostInput;
        use jsae_wire::{ActionBatch, PolicySnapshot};
        use ndarray::ArrayView2;
        use rand::SeedableRng;

        use crate::fused::{FusedWork, HostMinibatch, LossConfig};

        let (states, space, next) = logged();
        let with_prior = |seed| {
            let config = PpoConfig {
                recommender: RecommenderPpoConfig {
                    logged_prior: true,
                    ..RecommenderPpoConfig::default()
                },
                ..PpoConfig::default()
            };
            Learner::new(
                config,
                14,
                PolicyHead::Categorical { n: 6 },
                seed,
                3,
                DeviceKind::Flex,
            )
        };
        let mut l = with_prior(0);
        assert!(
            l.learn_from_logs(None).is_err(),
            "the settings ask for logs"
        );
        assert_eq!(l.count_prior(&states, &space, &next).expect("counts"), 36);
        let x = states.features(&space);
        let x = &x[..36 * 14];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (mut greedy, mut logp) = (ActionBatch::Discrete(Vec::new()), Vec::new());
        l.policy()
            .act(x, l.prior(), true, &mut rng, &mut greedy, &mut logp);
        assert_eq!(greedy, ActionBatch::Discrete(next[..36].to_vec()));

        // sampled actions: the fused loss's log-probabilities are the actor's (the sparse rows'
        // columns are read as the dense rows' non-zero ones: prior.rs's tests)
        let (mut sampled, mut logp) = (ActionBatch::Discrete(Vec::new()), Vec::new());
        l.policy()
            .act(x, l.prior(), false, &mut rng, &mut sampled, &mut logp);
        let ActionBatch::Discrete(a) = &sampled else {
            unreachable!()
        };
        let view = ArrayView2::from_shape((36, 14), x).expect("rows");
        let zeros = vec![0.0; 36];
        /// The largest |log-ratio| of the fused loss on `x`'s rows, actions `a` and
        /// behaviour log-probabilities `logp` (`zeros`: advantages, returns and values).
        fn max_log_ratio<'a>(
            host: &HostPolicy,
            x: HostInput<'a>,
            a: &'a [u32],
            logp: &'a [f32],
            zeros: &'a [f32],
        ) -> f32 {
            let mb = HostMinibatch {
                x,
                continuous: &[],
                discrete: a,
                old_logp: logp,
                adv: zeros,
                returns: zeros,
                old_values: zeros,
                next_purchase: &[],
            };
            let cfg = LossConfig {
                clip: 0.2,
                clip_value_loss: false,
                ent_coef: 0.0,
                vf_coef: 0.5,
                next_purchase_coef: 0.0,
            };
            let mut work = FusedWork::new(host);
            host.loss_and_grads(&[mb], cfg, &mut work);
            work.log_ratio().iter().fold(0.0f32, |m, r| m.max(r.abs()))
        }
        let mut host = l.host_policy();
        let r = max_log_ratio(&host, HostInput::Dense(view), a, &logp, &zeros);
        assert!(r < 1e-4, "{r}");
        host.prior = None;
        let without = max_log_ratio(&host, HostInput::Dense(view), a, &logp, &zeros);
        assert!(without > 0.5, "the prior is most of the logits: {without}");

        // a policy loaded from the bytes acts with the same prior
        let bytes = l.snapshot().expect("bytes").bytes;
        let mut other = with_prior(9);
        other
            .restore(&PolicySnapshot { version: 1, bytes })
            .expect("loads");
        assert!(other.prior().is_some());
        assert_eq!(
            other.policy().head_outputs(x, other.prior()),
            l.policy().head_outputs(x, l.prior())
        );
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
