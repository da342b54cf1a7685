//! The PPO update on the host (the default path): the batch's inputs normalised once, each
//! minibatch gathered into reused buffers, the loss and every gradient from
//! [`HostPolicy::loss_and_grads`], global grad-norm clipping and Adam on the host
//! ([`jsae_nn::host`]); the trained weights are written back into the burn policy at the end,
//! so snapshots, inference and checkpoints read the same parameters.

use jsae_nn::host::global_norm_rows;
use jsae_nn::{AdamMoments, HostAdam, clip_scale};
use rand::seq::SliceRandom;

use super::batch::{Batch, HostRows, NetworkInput};
use super::update::EpochStats;
use super::{Learner, UpdateMetrics};
use crate::fused::{FusedWork, HostPolicy, LossConfig, minibatch_parts};

/// The fused path's state between updates: Adam's moments and the reused buffers.
#[derive(Debug)]
pub(super) struct FusedState {
    adam: HostAdam,
    work: Option<FusedWork>,
    rows: HostRows,
}

impl FusedState {
    /// Adam with the learner's epsilon (1e-5, as the burn path's).
    pub(super) fn new() -> Self {
        Self {
            adam: HostAdam::new(super::ADAM_EPSILON),
            work: None,
            rows: HostRows::default(),
        }
    }

    /// Adam's step and moments (for a checkpoint).
    pub(super) fn adam_moments(&self) -> AdamMoments {
        self.adam.moments()
    }

    /// Goes on from saved Adam state.
    pub(super) fn set_adam_moments(&mut self, saved: AdamMoments) {
        self.adam.set_moments(saved);
    }
}

impl Learner {
    pub(super) fn optimise_fused(&mut self, batch: &Batch, lr: f64) -> UpdateMetrics {
        let mut host = HostPolicy::from_policy(&self.policy, self.prior.shared());
        let x = &batch.input;
        let (config, rng, state) = (&self.config, &mut self.rng, &mut self.fused);
        // on one of rayon's threads, so the per-minibatch joins inside stay cheap
        let metrics = rayon::scope(|_| {
            let mut order: Vec<usize> = (0..batch.len()).collect();
            epochs(config, batch, x, lr as f32, &mut host, state, || {
                order.shuffle(rng);
                order.clone()
            })
        });
        host.params.write_into(&mut self.policy);
        metrics
    }
}

/// The update's epochs over `batch` (network inputs `x`), each in the minibatch order
/// `shuffled` gives, stopping early when the KL target is passed.
pub(super) fn epochs(
    config: &crate::PpoConfig,
    batch: &Batch,
    x: &NetworkInput,
    lr: f32,
    host: &mut HostPolicy,
    state: &mut FusedState,
    mut shuffled: impl FnMut() -> Vec<usize>,
) -> UpdateMetrics {
    let cfg = LossConfig {
        clip: config.clip as f32,
        clip_value_loss: config.clip_value_loss,
        ent_coef: config.ent_coef as f32,
        vf_coef: config.vf_coef as f32,
        next_purchase_coef: config.recommender.next_purchase_coef as f32,
    };
    let work = state.work.get_or_insert_with(|| FusedWork::new(host));
    // the crossed feature's first layers are stepped only in the rows a minibatch touches
    let lazy = config.recommender.pair_buckets > 0 && matches!(x, NetworkInput::Sparse(_));
    work.accumulate_input_rows = lazy;
    let mut touched = Vec::new();
    let mb = config.minibatch_len(batch.len());
    let (mut grad_sum, mut grad_count) = (0.0, 0);
    let mut last = EpochStats::default();
    let mut epochs = 0;
    for _ in 0..config.epochs {
        let order = shuffled();
        let mut stats = EpochStats::default();
        for rows in order.chunks(mb) {
            // a short last minibatch may be split into fewer parts
            let parts = minibatch_parts(rows.len());
            state.rows.fill(batch, x, rows, config.norm_adv, parts);
            let rows = if lazy {
                state.rows.sparse_columns(&mut touched);
                host.params.input_rows(&touched)
            } else {
                Vec::new()
            };
            let loss = host.loss_and_grads(&state.rows.views(), cfg, work);
            let grads = work.grads().slices();
            let norm = global_norm_rows(&grads, &rows);
            grad_sum += f64::from(norm);
            grad_count += 1;
            let scale = clip_scale(norm, config.max_grad_norm);
            state
                .adam
                .step_rows(lr, scale, &mut host.params.slices_mut(), &grads, &rows);
            work.clear_grad_rows(&rows);
            stats.add(
                work.log_ratio(),
                cfg.clip,
                loss.pg,
                loss.value,
                loss.entropy,
            );
            stats.add_next_purchase(loss.next_purchase);
        }
        epochs += 1;
        last = stats;
        if config
            .target_kl
            .is_some_and(|target| last.approx_kl() > target)
        {
            break;
        }
    }
    last.metrics(epochs, grad_sum / f64::from(grad_count.max(1)))
}
