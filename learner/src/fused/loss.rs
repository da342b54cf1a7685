//! The PPO loss on one minibatch and its gradient, in two independent halves: the actor's
//! (clipped surrogate and entropy, through the head's log-probabilities) and the critic's
//! (the value loss). Each walks its samples once, writing the gradient at its MLP's output,
//! then runs that MLP's backward pass.

use jsae_nn::host::math;
use jsae_nn::{HostMlp, MlpWork};

use super::{FusedWork, HostMinibatch, HostPolicy, LossConfig, LossParts};
use crate::policy::{HALF_LOG_2PI, LOG_STD_MAX, LOG_STD_MIN, PolicyHead};

/// The clipped surrogate of one sample, `max(-A r, -A clip(r))` with `r = exp(log_ratio)`,
/// and its derivative with respect to the log-probability (a tie, or a NaN, takes the
/// unclipped branch, as burn's `max_pair` does).
pub(super) fn surrogate(log_ratio: f32, adv: f32, clip: f32) -> (f32, f32) {
    let r = log_ratio.exp();
    let unclipped = -adv * r;
    let clipped = -adv * r.clamp(1.0 - clip, 1.0 + clip);
    if clipped > unclipped {
        (clipped, 0.0)
    } else {
        (unclipped, -adv * r)
    }
}

/// What the actor's half writes: its MLP's buffers and gradients, the log-std's gradient,
/// and the log-ratios.
struct ActorOut<'a> {
    work: &'a mut MlpWork,
    grads: &'a mut HostMlp,
    log_std: &'a mut [f32],
    log_ratio: &'a mut Vec<f32>,
}

impl HostPolicy {
    /// The loss on `mb`; every parameter's gradient is left in `work` ([`FusedWork::grads`]).
    /// The actor's half and the critic's half run side by side (rayon's pool; one thread
    /// runs both in turn where no other is free).
    pub fn loss_and_grads(
        &self,
        mb: &HostMinibatch<'_>,
        cfg: LossConfig,
        work: &mut FusedWork,
    ) -> LossParts {
        let FusedWork {
            actor,
            critic,
            grads,
            log_ratio,
        } = work;
        let ((pg, entropy), value) = rayon::join(
            || {
                let out = ActorOut {
                    work: actor,
                    grads: &mut grads.actor,
                    log_std: grads.log_std.as_slice_mut().unwrap_or(&mut []),
                    log_ratio,
                };
                self.actor_pass(mb, cfg, out)
            },
            || self.critic_pass(mb, cfg, critic, &mut grads.critic),
        );
        LossParts {
            total: pg - cfg.ent_coef * entropy + cfg.vf_coef * value,
            pg,
            value,
            entropy,
        }
    }

    /// The surrogate and the mean entropy, and the actor's and log-std's gradients.
    fn actor_pass(
        &self,
        mb: &HostMinibatch<'_>,
        cfg: LossConfig,
        work: ActorOut<'_>,
    ) -> (f32, f32) {
        let p = &self.params;
        let b = mb.x.nrows();
        let bf = b as f32;
        p.actor.forward(mb.x, work.work);
        work.log_ratio.clear();
        let mut pg = 0.0;
        let mut d_ls = vec![0.0f32; p.log_std.len()];
        let entropy;
        let (out, d_out) = work.work.output_and_grad();
        let width = out.ncols().max(1);
        let out = out.as_slice().unwrap_or(&[]);
        let d_out = d_out.as_slice_mut().unwrap_or(&mut []);
        match self.head {
            PolicyHead::Gaussian { dim } => {
                let ls: Vec<f32> = p
                    .log_std
                    .iter()
                    .map(|v| v.clamp(LOG_STD_MIN, LOG_STD_MAX))
                    .collect();
                let passes: Vec<f32> = p
                    .log_std
                    .iter()
                    .map(|v| f32::from((LOG_STD_MIN..=LOG_STD_MAX).contains(v)))
                    .collect();
                let inv_sigma: Vec<f32> = ls.iter().map(|l| (-l).exp()).collect();
                let lp_const = -HALF_LOG_2PI * dim as f32 - ls.iter().sum::<f32>();
                let mut dz = vec![0.0f32; dim]; // z / sigma * dmu per component
                let mut zz = vec![0.0f32; dim]; // z^2 - 1 per component
                for (i, (o, d)) in out
                    .chunks_exact(width)
                    .zip(d_out.chunks_exact_mut(width))
                    .enumerate()
                {
                    let a = &mb.continuous[i * dim..(i + 1) * dim];
                    let mut lp = lp_const;
                    for j in 0..dim {
                        let (mu, dmu) = if self.tanh_mean {
                            let t = math::tanh(o[j]);
                            (t, 1.0 - t * t)
                        } else {
                            (o[j], 1.0)
                        };
                        let z = (a[j] - mu) * inv_sigma[j];
                        lp -= 0.5 * z * z;
                        dz[j] = z * inv_sigma[j] * dmu;
                        zz[j] = z * z - 1.0;
                    }
                    let lr = lp - mb.old_logp[i];
                    work.log_ratio.push(lr);
                    let (loss, dpg) = surrogate(lr, mb.adv[i], cfg.clip);
                    pg += loss;
                    let dpg = dpg / bf;
                    for j in 0..dim {
                        d[j] = dpg * dz[j];
                        d_ls[j] += dpg * zz[j] * passes[j];
                    }
                }
                entropy = ls.iter().sum::<f32>() + (0.5 + HALF_LOG_2PI) * dim as f32;
                for (g, pass) in d_ls.iter_mut().zip(&passes) {
                    *g -= cfg.ent_coef * pass;
                }
            }
            PolicyHead::Categorical { .. } => {
                let (pg_sum, ent_sum) =
                    super::categorical::rows(out, d_out, width, mb, cfg, work.log_ratio);
                pg = pg_sum;
                entropy = ent_sum / bf;
            }
        }
        p.actor.backward(mb.x, work.work, work.grads);
        work.log_std.copy_from_slice(&d_ls);
        (pg / bf, entropy)
    }

    /// The value loss `0.5 mean((v - R)^2)` (or of the larger of it and the clipped one) and
    /// the critic's gradients.
    fn critic_pass(
        &self,
        mb: &HostMinibatch<'_>,
        cfg: LossConfig,
        work: &mut MlpWork,
        grads: &mut HostMlp,
    ) -> f32 {
        let b = mb.x.nrows();
        let bf = b as f32;
        self.params.critic.forward(mb.x, work);
        let (value, dv) = work.output_and_grad();
        let mut v_loss = 0.0;
        for (i, (&v, g)) in value.iter().zip(dv.iter_mut()).enumerate() {
            let ret = mb.returns[i];
            let unclipped = (v - ret) * (v - ret);
            let grad = if cfg.clip_value_loss {
                let old = mb.old_values[i];
                let delta = v - old;
                let vc = old + delta.clamp(-cfg.clip, cfg.clip);
                let clipped = (vc - ret) * (vc - ret);
                if clipped > unclipped {
                    v_loss += clipped;
                    (vc - ret) * f32::from((-cfg.clip..=cfg.clip).contains(&delta))
                } else {
                    v_loss += unclipped;
                    v - ret
                }
            } else {
                v_loss += unclipped;
                v - ret
            };
            *g = grad * cfg.vf_coef / bf;
        }
        self.params.critic.backward(mb.x, work, grads);
        v_loss * 0.5 / bf
    }
}
