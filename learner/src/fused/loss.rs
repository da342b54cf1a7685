//! The PPO loss on one minibatch and its gradient, in two independent halves: the actor's
//! (clipped surrogate and entropy, through the head's log-probabilities) and the critic's
//! (the value loss). Each walks its samples once, writing the gradient at its MLP's output,
//! then runs that MLP's backward pass.

use jsae_nn::host::math;
use jsae_nn::{HostInput, HostMlp, InputWeights, MlpWork, OutputBias};

use super::{FusedWork, HostMinibatch, HostPolicy, LossConfig, LossParts, surrogate};
use jsae_agent::CountPrior;
use jsae_agent::policy::{HALF_LOG_2PI, LOG_STD_MAX, LOG_STD_MIN, PolicyHead};

/// What the actor's half writes: its MLP's buffers and gradients, the log-std's gradient,
/// and the log-ratios.
struct ActorOut<'a> {
    work: &'a mut MlpWork,
    grads: &'a mut HostMlp,
    log_std: &'a mut [f32],
    log_ratio: &'a mut Vec<f32>,
    input_weights: InputWeights,
}

/// One part's sums over its samples: the surrogate, the entropy (categorical; the Gaussian's
/// does not depend on the sample) and the squared value error.
#[derive(Debug, Clone, Copy, Default)]
struct PartSums {
    pg: f32,
    entropy: f32,
    value: f32,
    /// The next-purchase cross-entropy's sum (categorical, when on).
    next_nll: f32,
}

impl HostPolicy {
    /// The loss on the minibatch whose rows are `parts` (in order; see
    /// [`super::minibatch_parts`]); every parameter's gradient is left in `work`
    /// ([`FusedWork::grads`]). The parts run side by side, each with its actor's half and its
    /// critic's half side by side too (rayon's pool: a thread runs what no other takes), and
    /// their gradients are added in order, so the result does not depend on which thread
    /// ran what.
    pub fn loss_and_grads(
        &self,
        parts: &[HostMinibatch<'_>],
        cfg: LossConfig,
        work: &mut FusedWork,
    ) -> LossParts {
        use rayon::prelude::*;
        assert!(!parts.is_empty(), "a minibatch of no parts");
        let rows: usize = parts.iter().map(|mb| mb.x.nrows()).sum();
        // every sample's term is divided by the whole minibatch's size
        let bf = rows.max(1) as f32;
        // buffers of more parts than this minibatch has are kept for later ones
        while work.parts.len() < parts.len() {
            work.parts.push(super::PartWork::new(self));
        }
        let accumulate = work.accumulate_input_rows;
        let used = &mut work.parts[..parts.len()];
        let sums: Vec<PartSums> = parts
            .par_iter()
            .zip(used.par_iter_mut())
            .enumerate()
            .map(|(k, (mb, part))| {
                // one-hot inputs: the parts after the first add their few first-layer rows
                // into the first part's gradient afterwards
                let input_weights = match mb.x {
                    HostInput::Sparse(_) if k > 0 => InputWeights::ByCaller,
                    HostInput::Sparse(_) if accumulate => InputWeights::Accumulate,
                    _ => InputWeights::InPass,
                };
                self.part_pass(mb, cfg, bf, input_weights, part)
            })
            .collect();
        work.log_ratio.clear();
        for part in used.iter() {
            work.log_ratio.extend_from_slice(&part.log_ratio);
        }
        let (first, rest) = used.split_at_mut(1);
        let grads = &mut first[0].grads;
        let input_layers = self.params.input_layers();
        for (mb, other) in parts.iter().skip(1).zip(rest.iter()) {
            let sparse = match mb.x {
                HostInput::Sparse(x) => {
                    x.outer_add(other.actor.input_layer_grad(), &mut grads.actor.w[0]);
                    x.outer_add(other.critic.input_layer_grad(), &mut grads.critic.w[0]);
                    if let Some(skip) = grads.actor.skip.as_mut() {
                        x.outer_add(other.actor.output_grad(), skip);
                    }
                    true
                }
                HostInput::Dense(_) => false,
            };
            let mut part = other.grads.slices();
            if sparse {
                // added above, row by row; an empty slice adds nothing
                for &(i, _) in &input_layers {
                    part[i] = &[];
                }
            }
            jsae_nn::host::add_gradients(&mut grads.slices_mut(), &part);
        }
        let total = sums.iter().fold(PartSums::default(), |acc, s| PartSums {
            pg: acc.pg + s.pg,
            entropy: acc.entropy + s.entropy,
            value: acc.value + s.value,
            next_nll: acc.next_nll + s.next_nll,
        });
        let entropy = match self.head {
            PolicyHead::Gaussian { dim } => {
                // the mean entropy is the log-stds' (clamped) sum plus a constant; its
                // gradient, once per minibatch (the bonus stops at `entropy_log_std_max`)
                let hi = self.entropy_log_std_max;
                for (g, v) in grads.log_std.iter_mut().zip(&self.params.log_std) {
                    if (LOG_STD_MIN..=hi).contains(v) {
                        *g -= cfg.ent_coef;
                    }
                }
                self.params
                    .log_std
                    .iter()
                    .map(|v| v.clamp(LOG_STD_MIN, hi))
                    .sum::<f32>()
                    + (0.5 + HALF_LOG_2PI) * dim as f32
            }
            PolicyHead::Categorical { .. } => total.entropy / bf,
        };
        let (pg, value) = (total.pg / bf, total.value * 0.5 / bf);
        LossParts {
            total: pg - cfg.ent_coef * entropy
                + cfg.vf_coef * value
                + cfg.next_purchase_coef * total.next_nll / bf,
            pg,
            value,
            entropy,
            next_purchase: total.next_nll / bf,
        }
    }

    /// One part's sums, its actor's and critic's gradients into `part`'s buffers (the first
    /// layers' weight gradients only with [`InputWeights::InPass`]).
    fn part_pass(
        &self,
        mb: &HostMinibatch<'_>,
        cfg: LossConfig,
        bf: f32,
        input_weights: InputWeights,
        part: &mut super::PartWork,
    ) -> PartSums {
        let super::PartWork {
            actor,
            critic,
            grads,
            log_ratio,
        } = part;
        let ((pg, entropy, next_nll), value) = rayon::join(
            || {
                let out = ActorOut {
                    work: actor,
                    grads: &mut grads.actor,
                    log_std: grads.log_std.as_slice_mut().unwrap_or(&mut []),
                    log_ratio,
                    input_weights,
                };
                self.actor_pass(mb, cfg, bf, out)
            },
            || self.critic_pass(mb, cfg, bf, input_weights, critic, &mut grads.critic),
        );
        PartSums {
            pg,
            entropy,
            value,
            next_nll,
        }
    }

    /// The sums of the surrogate and (categorical) of the entropy over `mb`'s samples, and
    /// their terms' gradients for the actor and the log-std, each divided by `bf` (the whole
    /// minibatch's size; the Gaussian entropy's gradient is [`Self::loss_and_grads`]'s).
    fn actor_pass(
        &self,
        mb: &HostMinibatch<'_>,
        cfg: LossConfig,
        bf: f32,
        work: ActorOut<'_>,
    ) -> (f32, f32, f32) {
        let p = &self.params;
        // the softmax rows add the bias and sum its gradient as they go
        let output_bias = match self.head {
            PolicyHead::Gaussian { .. } => OutputBias::InPass,
            PolicyHead::Categorical { .. } => OutputBias::ByCaller,
        };
        p.actor.forward_with(mb.x, work.work, output_bias);
        work.log_ratio.clear();
        let mut pg = 0.0;
        let mut d_ls = vec![0.0f32; p.log_std.len()];
        let mut entropy = 0.0;
        let mut next_nll = 0.0;
        let (out, d_out) = work.work.output_mut_and_grad();
        let width = out.ncols().max(1);
        let out = out.as_slice_mut().unwrap_or(&mut []);
        if let Some(prior) = &self.prior {
            add_prior(prior, mb.x, width, out);
        }
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
            }
            PolicyHead::Categorical { .. } => {
                let last = p.actor.b.len() - 1;
                let bias = super::categorical::Bias {
                    value: p.actor.b[last].as_slice().unwrap_or(&[]),
                    grad: work.grads.b[last].as_slice_mut().unwrap_or(&mut []),
                };
                (pg, entropy, next_nll) =
                    super::categorical::rows(out, d_out, bias, mb, cfg, bf, work.log_ratio);
            }
        }
        p.actor
            .backward_with(mb.x, work.work, work.grads, output_bias, work.input_weights);
        work.log_std.copy_from_slice(&d_ls);
        (pg, entropy, next_nll)
    }

    /// The sum over `mb`'s samples of `(v - R)^2` (or of the larger of it and the clipped
    /// one; the value loss is half its mean over the minibatch), and the critic's gradients
    /// of the value loss's terms (`bf`: the whole minibatch's size).
    fn critic_pass(
        &self,
        mb: &HostMinibatch<'_>,
        cfg: LossConfig,
        bf: f32,
        input_weights: InputWeights,
        work: &mut MlpWork,
        grads: &mut HostMlp,
    ) -> f32 {
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
        self.params
            .critic
            .backward_with(mb.x, work, grads, OutputBias::InPass, input_weights);
        v_loss
    }
}

/// Adds `prior`'s logits for each row of `x` to its row of `out` (`[rows, width]`).
fn add_prior(prior: &CountPrior, x: HostInput<'_>, width: usize, out: &mut [f32]) {
    let mut cols = Vec::new();
    for (r, logits) in out.chunks_exact_mut(width).enumerate() {
        match x {
            HostInput::Sparse(x) => prior.add_to(x.row(r).0, logits),
            HostInput::Dense(x) => match x.row(r).to_slice() {
                Some(row) => prior.add_to_dense(row, logits, &mut cols),
                None => prior.add_to_dense(&x.row(r).to_vec(), logits, &mut cols),
            },
        }
    }
}
