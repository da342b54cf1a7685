//! Pre-training on logged purchases (`embedding.recommender.logged_pretrain_epochs`): before
//! the random-play pre-training, passes of shuffled minibatches over the logged steps (the
//! state before each purchase and the item bought) with the next-item loss alone. phi (its
//! pair rows too), g and the next-item head learn which items follow which contexts from
//! every logged purchase; the random-play pre-training then adds T's loss. A shop has its
//! purchase logs before it has a policy.

use std::sync::Arc;

use jsae_settings::LoggedTargets;
use jsae_wire::{CatalogueTag, StateBatch};
use rand::seq::SliceRandom;

use super::EmbedderTrainer;
use super::logged_estimate::CountedEstimate;
use super::logged_lookahead::LookaheadEstimate;
use crate::representation::{NextItemTargets, RepresentationModel};

/// Logged purchases: the state before each purchase, as the actors encode states, and the
/// item bought (the caller, which knows the data, reads them; the held-out sessions never).
#[derive(Debug, Clone)]
pub struct LoggedItems {
    /// The states.
    pub states: StateBatch,
    /// The item bought after each.
    pub items: Vec<u32>,
    /// The catalogue the items' slots are of: the snapshots carry it, so a process serving
    /// other items refuses them (None: not said).
    pub catalogue: Option<CatalogueTag>,
}

impl LoggedItems {
    /// Rows `rows` of the logs.
    fn gather(&self, rows: &[usize]) -> (StateBatch, Vec<u32>) {
        let items = rows.iter().map(|&r| self.items[r]).collect();
        // an empty batch of the logs' kind (not a copy of them: this runs per minibatch)
        let mut states = match &self.states {
            StateBatch::Categorical { factors, .. } => StateBatch::Categorical {
                factors: *factors,
                data: Vec::new(),
            },
            StateBatch::Real { dim, .. } => StateBatch::Real {
                dim: *dim,
                data: Vec::new(),
            },
        };
        for &r in rows {
            states.push_row_of(&self.states, r);
        }
        (states, items)
    }
}

/// What the logged pre-training did.
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedReport {
    /// Logged steps.
    pub samples: usize,
    /// Passes over them.
    pub epochs: usize,
    /// Mean next-item loss over the first pass's minibatches (nats).
    pub first_loss: f32,
    /// The same over the last pass's.
    pub last_loss: f32,
}

impl<M: RepresentationModel> EmbedderTrainer<M> {
    /// The logged purchases pre-training starts with (`embedding.recommender.
    /// logged_pretrain_epochs`; kept until then).
    ///
    /// # Errors
    /// When the states are not of the model's state space, the lengths differ, an item is
    /// not an action, or there are none.
    pub fn set_logged(&mut self, logged: Arc<LoggedItems>) -> Result<(), String> {
        let rows = logged.states.len();
        if rows == 0 || rows != logged.items.len() {
            return Err(format!(
                "logged purchases: {rows} states and {} items (both must be the same, and not 0)",
                logged.items.len()
            ));
        }
        jsae_wire::validate_states(&logged.states, self.model.state_space())
            .map_err(|e| format!("logged purchases: {e}"))?;
        let n = self.model.action_space().num_discrete().unwrap_or(0);
        if let Some(bad) = logged.items.iter().find(|&&i| i as usize >= n) {
            return Err(format!(
                "logged purchases: item {bad} is not one of the {n} actions"
            ));
        }
        let two_items =
            matches!(&logged.states, StateBatch::Categorical { factors, .. } if *factors >= 2);
        if self.logged_targets() != LoggedTargets::Bought && !two_items {
            return Err(
                "embedding.recommender.logged_targets: counted targets need states of two \
                 items or more (the estimate is keyed by the last two)"
                    .into(),
            );
        }
        self.logged = Some(logged);
        Ok(())
    }

    /// With the next-item head, every next state's last item must be an action (the head's
    /// target; the wire allows the "none" slot there, which no environment step produces).
    pub(super) fn check_next_items(
        &self,
        batch: &jsae_wire::TransitionBatch,
    ) -> Result<(), jsae_wire::ValidationError> {
        let (true, Some(n), StateBatch::Categorical { factors, data }) = (
            self.config.recommender.next_item(),
            self.model.action_space().num_discrete(),
            &batch.next_states,
        ) else {
            return Ok(());
        };
        let last = data
            .iter()
            .skip(factors.saturating_sub(1))
            .step_by((*factors).max(1));
        match last.copied().find(|&v| v as usize >= n) {
            Some(value) => Err(jsae_wire::ValidationError::OutOfRange {
                field: "next_states (the item bought, the next-item head's target)",
                value,
                limit: n,
            }),
            None => Ok(()),
        }
    }

    /// What the logged passes teach: `logged_targets`, except at catalogue scale
    /// (`embedding.sampled_softmax_from`), where a distribution over every item per state does
    /// not fit and the item bought is the target whatever the setting (the recommender's JSAE
    /// defaults ask for `counted-best`, and a million-item catalogue trains with them).
    fn logged_targets(&self) -> LoggedTargets {
        let (states, actions) = (self.model.state_space(), self.model.action_space());
        match self.config.recommender.logged_targets {
            _ if self.config.samples_items(states, actions) => LoggedTargets::Bought,
            targets => targets,
        }
    }

    /// The logs' interpolated estimate for `lookahead` targets, its lift set or measured on
    /// the random-play transitions in the replay buffer (1, no planning, when none of them
    /// bought the recommendation).
    fn lookahead_estimate(&self, logged: &LoggedItems) -> Option<LookaheadEstimate> {
        let items = self.model.action_space().num_discrete()?;
        let mut plan = LookaheadEstimate::count(&logged.states, &logged.items, items)?;
        let boost = match self.config.recommender.lookahead_boost {
            b if b > 0.0 => b,
            _ => {
                let play = self
                    .replay
                    .gather(&(0..self.replay.len()).collect::<Vec<_>>());
                let (
                    jsae_wire::ActionBatch::Discrete(actions),
                    StateBatch::Categorical { factors, data },
                ) = (&play.actions, &play.next_states)
                else {
                    return Some(plan);
                };
                let bought: Vec<u32> = data
                    .chunks_exact(*factors)
                    .map(|r| r[factors - 1])
                    .collect();
                let measured = plan.measure_boost(&play.states, actions, &bought);
                tracing::info!(
                    transitions = actions.len(),
                    bought = actions.iter().zip(&bought).filter(|(a, b)| a == b).count(),
                    "lookahead targets: a recommendation's lift measured on random play: {}",
                    measured.map_or("none bought, 1 (no planning)".into(), |b| format!("{b:.2}"))
                );
                measured.unwrap_or(1.0)
            }
        };
        plan.set_boost(boost);
        Some(plan)
    }

    /// The logged passes, when the settings ask and logs were given (None otherwise).
    pub(super) fn pretrain_on_logs(&mut self) -> Option<LoggedReport> {
        let epochs = self.config.recommender.logged_pretrain_epochs;
        let logged = self.logged.take()?;
        if epochs == 0 {
            return None;
        }
        let n = logged.items.len();
        let mut order: Vec<usize> = (0..n).collect();
        let bs = self.config.batch_size.min(n);
        // `logged_pretrain_lr` annealed linearly to 0 over the passes, or `lr` throughout
        let (lr0, anneal) = match self.config.recommender.logged_pretrain_lr {
            lr if lr > 0.0 => (lr, true),
            _ => (self.config.lr, false),
        };
        let mut losses = Vec::with_capacity(epochs);
        let started = std::time::Instant::now();
        let mut logged_at = started;
        let chunks = n.div_ceil(bs);
        // at most `logged_pretrain_max_steps` minibatches (a million items' logs are 20M
        // purchases: one pass is 4,883 minibatches of 4,096), the last pass cut short
        let total = (epochs * chunks).min(self.config.recommender.logged_pretrain_max_steps);
        let epochs = total.div_ceil(chunks);
        let mut taken = 0;
        // `counted` targets: the logs' estimate after each state, and states ahead
        let targets = self.logged_targets();
        if targets != self.config.recommender.logged_targets {
            tracing::info!(
                "logged passes: the item bought as the target at catalogue scale \
                 (embedding.recommender.logged_targets applies below \
                 embedding.sampled_softmax_from = {} items)",
                self.config.sampled_softmax_from
            );
        }
        let counted = (targets != LoggedTargets::Bought)
            .then(|| {
                let items = self.model.action_space().num_discrete().unwrap_or(0);
                CountedEstimate::count(&logged, items)
            })
            .flatten();
        let mut lookahead = (targets == LoggedTargets::Lookahead)
            .then(|| self.lookahead_estimate(&logged))
            .flatten();
        let ahead_share = self.config.recommender.logged_ahead_share;
        for epoch in 1..=epochs {
            order.shuffle(&mut self.rng);
            let (mut sum, mut count) = (0.0, 0);
            for rows in order.chunks(bs).take(total - taken) {
                let done = taken as f64 / total as f64;
                taken += 1;
                let lr = if anneal { lr0 * (1.0 - done) } else { lr0 };
                let step = match &counted {
                    Some(estimate) => {
                        let ahead = (ahead_share * rows.len() as f64).round() as usize;
                        let batch = estimate.batch(&logged, rows, ahead, &mut self.rng);
                        let best;
                        let targets = match (targets, lookahead.as_mut()) {
                            (LoggedTargets::Lookahead, Some(plan)) => {
                                best = plan.targets_of(&batch.states);
                                NextItemTargets::Bought(&best)
                            }
                            (LoggedTargets::CountedBest | LoggedTargets::Lookahead, _) => {
                                best = estimate.best_items(&batch.probs);
                                NextItemTargets::Bought(&best)
                            }
                            _ => NextItemTargets::Estimate(&batch.probs),
                        };
                        self.model.train_next_item_step(
                            &mut self.optim.0,
                            &batch.states,
                            targets,
                            lr,
                        )
                    }
                    None => {
                        let (states, items) = logged.gather(rows);
                        self.model.train_next_item_step(
                            &mut self.optim.0,
                            &states,
                            NextItemTargets::Bought(&items),
                            lr,
                        )
                    }
                };
                if let Some(l) = step {
                    sum += l;
                    count += 1;
                }
            }
            losses.push(sum / count.max(1) as f32);
            if logged_at.elapsed().as_secs() >= 10 {
                logged_at = std::time::Instant::now();
                let left = started.elapsed().as_secs_f64() / epoch as f64 * (epochs - epoch) as f64;
                tracing::info!(
                    "pre-training the embedding on {n} logged purchases: epoch {epoch}/{epochs}, \
                     next-item loss {:.3}, about {left:.0} s left",
                    sum / count.max(1) as f32
                );
            }
        }
        let report = LoggedReport {
            samples: n,
            epochs,
            first_loss: losses.first().copied().unwrap_or(f32::NAN),
            last_loss: losses.last().copied().unwrap_or(f32::NAN),
        };
        tracing::info!(
            samples = n,
            epochs,
            first_loss = report.first_loss,
            last_loss = report.last_loss,
            "embedding pre-trained on the logged purchases (next-item loss)"
        );
        Some(report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::EmbeddingTraining;
    use jsae_nn::{DeviceKind, to_vec};
    use jsae_settings::{EmbeddingConfig, Representation};
    use jsae_wire::{ActionBatch, ActionSpace, StateSpace, TransitionBatch};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const ITEMS: u32 = 12;

    /// Two-item states (slot `ITEMS` is "none"); the item bought after `(b, l)` is
    /// `(b + 2 l) mod ITEMS`: a pair's, not either item's alone.
    fn logs(rows: usize, rng: &mut ChaCha8Rng) -> LoggedItems {
        let mut data = Vec::new();
        let mut items = Vec::new();
        for _ in 0..rows {
            let (b, l) = (rng.random_range(0..ITEMS), rng.random_range(0..ITEMS));
            data.extend([b, l]);
            items.push((b + 2 * l) % ITEMS);
        }
        LoggedItems {
            states: StateBatch::Categorical { factors: 2, data },
            items,
            catalogue: None,
        }
    }

    fn trainer(epochs: usize) -> EmbedderTrainer {
        let mut config = EmbeddingConfig {
            state_dim: 8,
            action_dim: 6,
            pretrain_transitions: 256,
            pretrain_per_action: 0,
            pretrain_epochs: 1,
            batch_size: 64,
            ..EmbeddingConfig::default()
        };
        config.recommender.next_item_coef = 1.0;
        config.recommender.pair_buckets = 4096;
        config.recommender.logged_pretrain_epochs = epochs;
        let states = StateSpace::Categorical {
            sizes: vec![ITEMS as usize + 1; 2],
        };
        let actions = ActionSpace::Discrete { n: ITEMS as usize };
        EmbedderTrainer::new(
            config,
            Representation::Jsae,
            &states,
            &actions,
            3,
            DeviceKind::Flex,
        )
    }

    fn random_play(rng: &mut ChaCha8Rng) -> TransitionBatch {
        let n = 256;
        let s: Vec<u32> = (0..2 * n).map(|_| rng.random_range(0..ITEMS)).collect();
        let a: Vec<u32> = (0..n).map(|_| rng.random_range(0..ITEMS)).collect();
        let next = s
            .chunks_exact(2)
            .flat_map(|p| [p[1], rng.random_range(0..ITEMS)])
            .collect();
        TransitionBatch {
            actor_id: 0,
            states: StateBatch::Categorical {
                factors: 2,
                data: s,
            },
            actions: ActionBatch::Discrete(a),
            rewards: vec![0.0; n],
            next_states: StateBatch::Categorical {
                factors: 2,
                data: next,
            },
            terminated: vec![false; n],
        }
    }

    /// The share of `logs` whose bought item is the one nearest to the head's output.
    fn hits(t: &EmbedderTrainer, logs: &LoggedItems) -> f64 {
        let logits = t
            .model()
            .next_item_logits(t.model().embed_states(&logs.states))
            .expect("the head");
        let logits = to_vec(logits);
        let n = ITEMS as usize;
        let right = logits
            .chunks_exact(n)
            .zip(&logs.items)
            .filter(|(row, item)| {
                let best = (0..n).max_by(|&i, &j| row[i].total_cmp(&row[j]));
                best == Some(**item as usize)
            })
            .count();
        right as f64 / logs.items.len() as f64
    }

    #[test]
    fn the_logs_teach_the_head_what_follows_a_pair() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let logged = Arc::new(logs(2048, &mut rng));
        let mut results = Vec::new();
        for epochs in [0, 40] {
            let mut t = trainer(epochs);
            t.set_logged(logged.clone()).expect("fits");
            let before = t.model().next_item_loss(&logged.states, &logged.items);
            let before = before.expect("the head").into_scalar::<f32>();
            t.ingest(&random_play(&mut rng)).expect("valid");
            t.poll().expect("serialises").expect("pre-trained");
            let after = t.model().next_item_loss(&logged.states, &logged.items);
            results.push((
                before,
                after.expect("head").into_scalar::<f32>(),
                hits(&t, &logged),
            ));
        }
        let (without, with) = (results[0], results[1]);
        assert!(with.1 < 0.3 * with.0, "the loss falls: {with:?}");
        assert!(
            with.2 > 0.6,
            "the nearest item is mostly the one bought: {with:?}"
        );
        assert!(
            without.2 < 0.3,
            "random play alone does not teach it: {without:?}"
        );
    }

    #[test]
    fn counted_targets_and_states_ahead_teach_the_head_too() {
        for targets in [
            LoggedTargets::Counted,
            LoggedTargets::CountedBest,
            LoggedTargets::Lookahead,
        ] {
            let mut rng = ChaCha8Rng::seed_from_u64(6);
            let logged = Arc::new(logs(2048, &mut rng));
            let mut t = trainer(40);
            t.config.recommender.logged_targets = targets;
            t.config.recommender.logged_ahead_share = 0.25;
            t.set_logged(logged.clone()).expect("fits");
            t.ingest(&random_play(&mut rng)).expect("valid");
            t.poll().expect("serialises").expect("pre-trained");
            let hit = hits(&t, &logged);
            assert!(
                hit > 0.6,
                "{targets:?}: the nearest item is mostly the one bought: {hit}"
            );
        }
    }

    #[test]
    fn at_catalogue_scale_the_logged_passes_teach_the_item_bought() {
        let mut t = trainer(1);
        t.config.recommender.logged_targets = LoggedTargets::CountedBest;
        assert_eq!(t.logged_targets(), LoggedTargets::CountedBest);
        // the recommender's JSAE defaults ask for counted targets at every size
        t.config.sampled_softmax_from = ITEMS as usize;
        assert_eq!(t.logged_targets(), LoggedTargets::Bought);
    }

    #[test]
    fn logs_that_do_not_fit_are_refused() {
        let mut t = trainer(1);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut bad = logs(10, &mut rng);
        bad.items[3] = ITEMS;
        let reason = t.set_logged(Arc::new(bad)).expect_err("no such item");
        assert!(reason.contains("not one of the 12 actions"), "{reason}");
        let mut short = logs(10, &mut rng);
        short.items.pop();
        assert!(t.set_logged(Arc::new(short)).is_err());
        let wide = LoggedItems {
            states: StateBatch::Categorical {
                factors: 2,
                data: vec![ITEMS + 1, 0],
            },
            items: vec![0],
            catalogue: None,
        };
        assert!(
            t.set_logged(Arc::new(wide)).is_err(),
            "a state out of range"
        );
        // from the wire: a next state whose last item is the "none" slot is no target
        let mut batch = random_play(&mut rng);
        if let StateBatch::Categorical { data, .. } = &mut batch.next_states {
            data[1] = ITEMS;
        }
        let reason = t.ingest(&batch).expect_err("no such item").to_string();
        assert!(reason.contains("next-item head"), "{reason}");
    }
}
