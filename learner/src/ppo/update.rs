//! One PPO update over a complete batch: epochs of shuffled minibatches, the clipped
//! surrogate, the (optionally clipped) value loss and the entropy bonus, global grad-norm
//! clipping, Adam, and the KL early stop; with the statistics each epoch reports.
//!
//! Two paths compute it: the fused one (`fused_update`, the default: host loss, gradients
//! and Adam) and burn's autodiff graph (here; the reference the fused path is checked
//! against, kept for `jsae bench --learner`'s old-versus-new comparison).

use burn::optim::GradientsParams;
use burn::tensor::Tensor;
use jsae_nn as nn;
use rand::seq::SliceRandom;

use super::batch::Batch;
use super::{Learner, UpdateMetrics};
use crate::PolicyEval;
use crate::fused::LOG_RATIO_MAX;
use jsae_agent::{Policy, PolicyHead};
use jsae_settings::UpdatePath;
use jsae_wire::ActionBatch;

impl Learner {
    pub(super) fn optimise(&mut self, batch: &Batch, lr: f64) -> UpdateMetrics {
        let metrics = match self.config.update {
            UpdatePath::Fused => self.optimise_fused(batch, lr),
            UpdatePath::Burn => self.optimise_burn(batch, lr),
        };
        UpdateMetrics {
            explained_variance: batch.explained_variance(),
            ..metrics
        }
    }

    fn optimise_burn(&mut self, batch: &Batch, lr: f64) -> UpdateMetrics {
        let n = batch.len();
        let device = self.policy.device().clone();
        let mut order: Vec<usize> = (0..n).collect();
        let mb = self.config.minibatch_len(n);
        let clip = self.config.clip as f32;
        let (mut grad_sum, mut grad_count) = (0.0, 0);
        let mut last = EpochStats::default();
        let mut epochs = 0;
        for _ in 0..self.config.epochs {
            order.shuffle(&mut self.rng);
            let mut stats = EpochStats::default();
            for rows in order.chunks(mb) {
                let m = batch.minibatch(rows, self.config.norm_adv, &device);
                let next_nll = next_purchase_nll(
                    &self.policy,
                    &m.x,
                    &m.next_purchase,
                    self.config.recommender.next_purchase_coef,
                );
                let eval = self.policy.evaluate(m.x, &m.actions);
                let log_ratio = eval.logp - m.old_logp;
                let pg_loss = clipped_surrogate_loss(log_ratio.clone(), m.adv, clip);
                let v_loss = if self.config.clip_value_loss {
                    let unclipped = (eval.value.clone() - m.returns.clone()).square();
                    let clipped_v =
                        m.old_values.clone() + (eval.value - m.old_values).clamp(-clip, clip);
                    let clipped = (clipped_v - m.returns).square();
                    unclipped.max_pair(clipped).mean().mul_scalar(0.5)
                } else {
                    (eval.value - m.returns).square().mean().mul_scalar(0.5)
                };
                let entropy = eval.entropy.mean();
                let mut loss = pg_loss.clone()
                    - entropy.clone().mul_scalar(self.config.ent_coef as f32)
                    + v_loss.clone().mul_scalar(self.config.vf_coef as f32);
                if let Some(nll) = next_nll {
                    loss = loss + nll.mul_scalar(self.config.recommender.next_purchase_coef as f32);
                }
                let mut grads = GradientsParams::from_grads(loss.backward(), self.policy.net());
                let norm = nn::clip_global_grad_norm(
                    self.policy.net(),
                    &mut grads,
                    self.config.max_grad_norm,
                );
                grad_sum += f64::from(norm);
                grad_count += 1;
                let net = self.optim.0.step(lr, self.policy.net().clone(), grads);
                self.policy.set_net(net);
                let lr_host = nn::to_vec(log_ratio.detach());
                stats.add(
                    &lr_host,
                    clip,
                    pg_loss.into_scalar::<f32>(),
                    v_loss.into_scalar::<f32>(),
                    entropy.into_scalar::<f32>(),
                );
            }
            epochs += 1;
            last = stats;
            if self
                .config
                .target_kl
                .is_some_and(|target| last.approx_kl() > target)
            {
                break;
            }
        }
        last.metrics(epochs, grad_sum / f64::from(grad_count.max(1)))
    }
}

/// The next-purchase cross-entropy of a categorical policy: `-log pi(t | x)` summed over the
/// samples with a next purchase `t` and divided by all `b` samples (as the fused path's
/// sums); None when the loss is off.
pub(crate) fn next_purchase_nll(
    policy: &Policy,
    x: &Tensor<2>,
    targets: &[u32],
    coef: f64,
) -> Option<Tensor<1>> {
    let PolicyHead::Categorical { n } = policy.head() else {
        return None;
    };
    if coef <= 0.0 || targets.is_empty() {
        return None;
    }
    let valid = |t: u32| (t as usize) < n;
    let actions = ActionBatch::Discrete(
        targets
            .iter()
            .map(|&t| if valid(t) { t } else { 0 })
            .collect(),
    );
    let mask: Vec<f32> = targets
        .iter()
        .map(|&t| f32::from(u8::from(valid(t))))
        .collect();
    let logp = policy.evaluate(x.clone(), &actions).logp;
    let mask = nn::tensor1(mask, &policy.device().clone());
    Some((logp * mask).sum().neg().div_scalar(targets.len() as f32))
}

/// PPO's clipped surrogate: `mean(max(-A r, -A clip(r, 1-c, 1+c)))` with
/// `r = exp(min(log_ratio, LOG_RATIO_MAX))`, all `[batch]`.
pub fn clipped_surrogate_loss(log_ratio: Tensor<1>, adv: Tensor<1>, clip: f32) -> Tensor<1> {
    let ratio = log_ratio.clamp_max(LOG_RATIO_MAX).exp();
    let unclipped = ratio.clone() * adv.clone().neg();
    let clipped = ratio.clamp(1.0 - clip, 1.0 + clip) * adv.neg();
    unclipped.max_pair(clipped).mean()
}

/// What one epoch's minibatches report, summed.
#[derive(Debug, Default)]
pub(super) struct EpochStats {
    pg: f64,
    v: f64,
    ent: f64,
    next: f64,
    kl: f64,
    clipped: f64,
    samples: f64,
    minibatches: f64,
}

impl EpochStats {
    pub(super) fn add(&mut self, log_ratio: &[f32], clip: f32, pg: f32, v: f32, ent: f32) {
        for &lr in log_ratio {
            let r = lr.exp();
            self.kl += f64::from((r - 1.0) - lr);
            if (r - 1.0).abs() > clip {
                self.clipped += 1.0;
            }
        }
        self.samples += log_ratio.len() as f64;
        self.pg += f64::from(pg);
        self.v += f64::from(v);
        self.ent += f64::from(ent);
        self.minibatches += 1.0;
    }

    fn mean(&self, sum: f64) -> f64 {
        sum / self.minibatches.max(1.0)
    }

    /// Adds one minibatch's next-purchase cross-entropy (call after [`Self::add`]).
    pub(super) fn add_next_purchase(&mut self, nll: f32) {
        self.next += f64::from(nll);
    }

    pub(super) fn approx_kl(&self) -> f64 {
        self.kl / self.samples.max(1.0)
    }

    fn clip_frac(&self) -> f64 {
        self.clipped / self.samples.max(1.0)
    }

    /// The update's metrics from its last epoch.
    pub(super) fn metrics(&self, epochs: usize, grad_norm: f64) -> UpdateMetrics {
        UpdateMetrics {
            policy_loss: self.mean(self.pg),
            value_loss: self.mean(self.v),
            entropy: self.mean(self.ent),
            next_purchase_loss: self.mean(self.next),
            approx_kl: self.approx_kl(),
            clip_frac: self.clip_frac(),
            grad_norm,
            epochs,
            ..UpdateMetrics::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_nn::{BurnDevice, DeviceKind};

    #[test]
    fn clipped_surrogate_matches_hand_computed_values() {
        let device = DeviceKind::Flex.device();
        // ratios 1.5, 0.5, 1.1, 0.7 with advantages 1, 1, -2, -1 and clip 0.2:
        //  1.5, A=1:  max(-1.5, -1.2) = -1.2
        //  0.5, A=1:  max(-0.5, -0.8) = -0.5
        //  1.1, A=-2: max(2.2, 2.2)   =  2.2
        //  0.7, A=-1: max(0.7, 0.8)   =  0.8
        // mean = (-1.2 - 0.5 + 2.2 + 0.8) / 4 = 0.325
        let ratios: [f32; 4] = [1.5, 0.5, 1.1, 0.7];
        let log_ratio = nn::tensor1(ratios.iter().map(|r| r.ln()).collect(), &device);
        let adv = nn::tensor1(vec![1.0, 1.0, -2.0, -1.0], &device);
        let loss = clipped_surrogate_loss(log_ratio, adv, 0.2).into_scalar::<f32>();
        assert!((loss - 0.325).abs() < 1e-5, "{loss}");
    }
}
