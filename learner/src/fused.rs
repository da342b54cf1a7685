//! The PPO minibatch loss and its gradient computed on the host in one pass, with the dense
//! products on a GEMM kernel (ndarray's matrixmultiply), instead of a graph of ~30 small
//! tensor operations through burn's autodiff. Same model, same parameters: [`HostPolicy`] is
//! read from the burn [`Policy`] (burn's `Linear` weights are `[in, out]`), and the gradients
//! come out in the same layout. The loss is the one `ppo::update` builds: the clipped
//! surrogate, minus `ent_coef` times the mean entropy, plus `vf_coef` times the (optionally
//! clipped) value loss; where burn's `max_pair` has a tie the gradient goes to the unclipped
//! term, as burn's does.
//!
//! This is the first part of the fused update; the optimiser step still runs through burn.

use ndarray::{Array1, Array2, ArrayView2, Axis};

use crate::policy::{HALF_LOG_2PI, LOG_STD_MAX, LOG_STD_MIN, Policy, PolicyHead};

/// An MLP's weights on the host: `w[i]` is `[in, out]`, `b[i]` is `[out]`; tanh between
/// layers, none after the last.
#[derive(Debug, Clone, PartialEq)]
pub struct HostMlp {
    /// Weights per layer, `[in, out]`.
    pub w: Vec<Array2<f32>>,
    /// Biases per layer, `[out]`.
    pub b: Vec<Array1<f32>>,
}

impl HostMlp {
    fn from_burn(mlp: &jsae_nn::Mlp) -> Self {
        let mut w = Vec::new();
        let mut b = Vec::new();
        for layer in mlp.layers() {
            let weight = layer.weight.val();
            let [rows, cols] = weight.dims();
            let data = jsae_nn::to_vec(weight);
            w.push(
                Array2::from_shape_vec((rows, cols), data)
                    .unwrap_or_else(|_| Array2::zeros((rows, cols))),
            );
            let bias = layer
                .bias
                .as_ref()
                .map_or_else(|| vec![0.0; cols], |p| jsae_nn::to_vec(p.val()));
            b.push(Array1::from(bias));
        }
        Self { w, b }
    }

    /// The layers' outputs: `acts[0] = x`, `acts[i]` after layer `i` (tanh applied except
    /// for the last).
    fn forward(&self, x: ArrayView2<'_, f32>) -> Vec<Array2<f32>> {
        let last = self.w.len().saturating_sub(1);
        let mut acts = vec![x.to_owned()];
        for (i, (w, b)) in self.w.iter().zip(&self.b).enumerate() {
            let mut z = acts[i].dot(w) + b;
            if i < last {
                z.mapv_inplace(f32::tanh);
            }
            acts.push(z);
        }
        acts
    }

    /// Gradients of the weights and biases, given the gradient at the output.
    fn backward(&self, acts: &[Array2<f32>], mut grad: Array2<f32>) -> HostMlp {
        let n = self.w.len();
        let mut gw = vec![Array2::zeros((0, 0)); n];
        let mut gb = vec![Array1::zeros(0); n];
        for i in (0..n).rev() {
            gw[i] = acts[i].t().dot(&grad);
            gb[i] = grad.sum_axis(Axis(0));
            if i > 0 {
                let mut g = grad.dot(&self.w[i].t());
                // through the tanh of layer i-1: d tanh = 1 - tanh^2
                g.zip_mut_with(&acts[i], |g, &a| *g *= 1.0 - a * a);
                grad = g;
            }
        }
        HostMlp { w: gw, b: gb }
    }
}

/// The policy's trainable parameters on the host (and, for gradients, their layout).
#[derive(Debug, Clone, PartialEq)]
pub struct HostParams {
    /// The actor MLP.
    pub actor: HostMlp,
    /// The critic MLP.
    pub critic: HostMlp,
    /// The log-std parameter (Gaussian; one unused value for categorical), unclamped.
    pub log_std: Array1<f32>,
}

/// The gradient of the loss for every parameter, in the parameters' layout.
pub type HostGrads = HostParams;

/// A policy on the host: its parameters and its head.
#[derive(Debug, Clone, PartialEq)]
pub struct HostPolicy {
    /// The trainable parameters.
    pub params: HostParams,
    /// The output distribution.
    pub head: PolicyHead,
    /// Whether the Gaussian mean is tanh-bounded.
    pub tanh_mean: bool,
}

/// One minibatch, as `ppo::update` builds it (advantages already normalised if configured).
#[derive(Debug, Clone)]
pub struct HostMinibatch<'a> {
    /// Network inputs (normalised when the policy normalises), `[b, input]`.
    pub x: ArrayView2<'a, f32>,
    /// Gaussian actions `[b * dim]`, or empty.
    pub continuous: &'a [f32],
    /// Categorical actions `[b]`, or empty.
    pub discrete: &'a [u32],
    /// Behaviour log-probabilities.
    pub old_logp: &'a [f32],
    /// Advantages.
    pub adv: &'a [f32],
    /// Returns.
    pub returns: &'a [f32],
    /// Values at collection time.
    pub old_values: &'a [f32],
}

/// The loss's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossConfig {
    /// Surrogate (and value) clip range.
    pub clip: f32,
    /// Clip the value loss.
    pub clip_value_loss: bool,
    /// Entropy coefficient.
    pub ent_coef: f32,
    /// Value-loss coefficient.
    pub vf_coef: f32,
}

/// The loss's parts, as `ppo::update` reports them.
#[derive(Debug, Clone, PartialEq)]
pub struct LossParts {
    /// The whole loss.
    pub total: f32,
    /// Clipped surrogate.
    pub pg: f32,
    /// Value loss.
    pub value: f32,
    /// Mean entropy.
    pub entropy: f32,
    /// `logp - old_logp` per sample.
    pub log_ratio: Vec<f32>,
}

impl HostPolicy {
    /// The trainable parameters of `policy`, copied to the host.
    pub fn from_policy(policy: &Policy) -> Self {
        let (actor, critic, log_std) = policy.parts();
        Self {
            params: HostParams {
                actor: HostMlp::from_burn(actor),
                critic: HostMlp::from_burn(critic),
                log_std: Array1::from(jsae_nn::to_vec(log_std.val())),
            },
            head: policy.head(),
            tanh_mean: policy.tanh_mean(),
        }
    }

    /// The loss on `mb` and its gradient with respect to every parameter.
    pub fn loss_and_grads(
        &self,
        mb: &HostMinibatch<'_>,
        cfg: LossConfig,
    ) -> (LossParts, HostGrads) {
        let p = &self.params;
        let head = self.head;
        let b = mb.x.nrows();
        let bf = b as f32;
        let actor_acts = p.actor.forward(mb.x);
        let critic_acts = p.critic.forward(mb.x);
        let out = actor_acts
            .last()
            .cloned()
            .unwrap_or_else(|| Array2::zeros((b, 0)));
        let value = critic_acts
            .last()
            .map_or_else(|| vec![0.0; b], |v| v.column(0).to_vec());

        // log-probabilities and their gradients with respect to the actor's output
        let mut logp = vec![0.0f32; b];
        let mut dlogp_dout = Array2::<f32>::zeros(out.raw_dim()); // per sample, unscaled
        let mut d_out_entropy = Array2::<f32>::zeros(out.raw_dim()); // d mean(entropy) / d out
        let mut dlogp_dls = Array2::<f32>::zeros((b, p.log_std.len()));
        let mut d_ls_entropy = Array1::<f32>::zeros(p.log_std.len());
        let entropy_mean;
        match head {
            PolicyHead::Gaussian { dim } => {
                let ls: Vec<f32> = p
                    .log_std
                    .iter()
                    .map(|v| v.clamp(LOG_STD_MIN, LOG_STD_MAX))
                    .collect();
                let ls_passes: Vec<f32> = p
                    .log_std
                    .iter()
                    .map(|v| f32::from((LOG_STD_MIN..=LOG_STD_MAX).contains(v)))
                    .collect();
                for i in 0..b {
                    let mut lp = -HALF_LOG_2PI * dim as f32;
                    for j in 0..dim {
                        let o = out[[i, j]];
                        let (mu, dmu) = if self.tanh_mean {
                            let t = o.tanh();
                            (t, 1.0 - t * t)
                        } else {
                            (o, 1.0)
                        };
                        let sigma = ls[j].exp();
                        let z = (mb.continuous[i * dim + j] - mu) / sigma;
                        lp += -0.5 * z * z - ls[j];
                        dlogp_dout[[i, j]] = z / sigma * dmu;
                        dlogp_dls[[i, j]] = (z * z - 1.0) * ls_passes[j];
                    }
                    logp[i] = lp;
                }
                entropy_mean = ls.iter().sum::<f32>() + (0.5 + HALF_LOG_2PI) * dim as f32;
                d_ls_entropy.assign(&Array1::from(ls_passes));
            }
            PolicyHead::Categorical { n } => {
                let mut ent_sum = 0.0;
                for i in 0..b {
                    let row = out.row(i);
                    let max = row.fold(f32::NEG_INFINITY, |m, &v| m.max(v));
                    let z: f32 = row.iter().map(|&v| (v - max).exp()).sum();
                    let log_z = max + z.ln();
                    let a = mb.discrete[i] as usize;
                    logp[i] = row[a] - log_z;
                    let mut h = 0.0;
                    for k in 0..n {
                        let lp = row[k] - log_z;
                        h -= lp.exp() * lp;
                    }
                    ent_sum += h;
                    for k in 0..n {
                        let lp = row[k] - log_z;
                        let p = lp.exp();
                        dlogp_dout[[i, k]] = f32::from(k == a) - p;
                        d_out_entropy[[i, k]] = -p * (lp + h) / bf;
                    }
                }
                entropy_mean = ent_sum / bf;
            }
        }

        // clipped surrogate: mean(max(-A r, -A clip(r))); a tie takes the unclipped branch
        let mut pg = 0.0;
        let mut dpg_dlogp = vec![0.0f32; b];
        let mut log_ratio = Vec::with_capacity(b);
        for i in 0..b {
            let lr = logp[i] - mb.old_logp[i];
            log_ratio.push(lr);
            let r = lr.exp();
            let a = mb.adv[i];
            let unclipped = -a * r;
            let clipped = -a * r.clamp(1.0 - cfg.clip, 1.0 + cfg.clip);
            if unclipped >= clipped {
                pg += unclipped;
                dpg_dlogp[i] = -a * r / bf;
            } else {
                pg += clipped;
            }
        }
        pg /= bf;

        // value loss: 0.5 mean((v - R)^2), or of the larger of it and the clipped one
        let mut v_loss = 0.0;
        let mut dv = Array2::<f32>::zeros((b, 1));
        for i in 0..b {
            let (v, ret) = (value[i], mb.returns[i]);
            let unclipped = (v - ret) * (v - ret);
            if cfg.clip_value_loss {
                let old = mb.old_values[i];
                let delta = v - old;
                let vc = old + delta.clamp(-cfg.clip, cfg.clip);
                let clipped = (vc - ret) * (vc - ret);
                if unclipped >= clipped {
                    v_loss += unclipped;
                    dv[[i, 0]] = (v - ret) / bf;
                } else {
                    v_loss += clipped;
                    let passes = f32::from((-cfg.clip..=cfg.clip).contains(&delta));
                    dv[[i, 0]] = (vc - ret) / bf * passes;
                }
            } else {
                v_loss += unclipped;
                dv[[i, 0]] = (v - ret) / bf;
            }
        }
        v_loss *= 0.5 / bf;
        dv.mapv_inplace(|g| g * cfg.vf_coef);

        // d loss / d out = dpg/dlogp * dlogp/dout - ent_coef * d entropy / d out
        let mut d_out = dlogp_dout;
        for (i, mut row) in d_out.rows_mut().into_iter().enumerate() {
            row.mapv_inplace(|g| g * dpg_dlogp[i]);
        }
        d_out.scaled_add(-cfg.ent_coef, &d_out_entropy);
        let mut d_log_std = Array1::<f32>::zeros(p.log_std.len());
        if let PolicyHead::Gaussian { .. } = head {
            for (i, row) in dlogp_dls.rows().into_iter().enumerate() {
                d_log_std.scaled_add(dpg_dlogp[i], &row);
            }
            d_log_std.scaled_add(-cfg.ent_coef, &d_ls_entropy);
        }
        let grads = HostParams {
            actor: p.actor.backward(&actor_acts, d_out),
            critic: p.critic.backward(&critic_acts, dv),
            log_std: d_log_std,
        };
        let total = pg - cfg.ent_coef * entropy_mean + cfg.vf_coef * v_loss;
        let parts = LossParts {
            total,
            pg,
            value: v_loss,
            entropy: entropy_mean,
            log_ratio,
        };
        (parts, grads)
    }
}

#[cfg(test)]
mod tests {
    //! The host loss and gradient against burn's autodiff on the same weights and minibatch,
    //! for each head, with and without the tanh mean and the value clip.

    use super::*;
    use crate::PpoConfig;
    use crate::ppo::clipped_surrogate_loss;
    use burn::tensor::Tensor;
    use jsae_nn::{BurnDevice, DeviceKind};
    use jsae_proto::ActionBatch;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn close(a: &[f32], b: &[f32], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}");
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-4 * scale + 1e-7,
                "{what}[{i}]: host {x}, burn {y} (scale {scale})"
            );
        }
    }

    fn check(head: PolicyHead, tanh_mean: bool, clip_value_loss: bool) {
        let device = DeviceKind::Flex.train_device();
        let mut config = PpoConfig {
            tanh_mean,
            clip_value_loss,
            init_log_std: -0.3,
            ..PpoConfig::default()
        };
        config.normalize_obs = false;
        let input = 7;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let policy = Policy::new(&config, input, head, &mut rng, &device);
        let b = 48;
        let x: Vec<f32> = (0..b * input)
            .map(|_| rng.random_range(-2.0..2.0))
            .collect();
        let actions = match head {
            PolicyHead::Gaussian { dim } => ActionBatch::Continuous {
                dim,
                data: (0..b * dim).map(|_| rng.random_range(-1.2..1.2)).collect(),
            },
            PolicyHead::Categorical { n } => {
                ActionBatch::Discrete((0..b).map(|_| rng.random_range(0..n as u32)).collect())
            }
        };
        // behaviour log-probs near the current ones, so some ratios are clipped and some not
        let current = jsae_nn::to_vec(
            policy
                .evaluate(jsae_nn::tensor2(x.clone(), b, input, &device), &actions)
                .logp,
        );
        let old_logp: Vec<f32> = current
            .iter()
            .map(|l| l + rng.random_range(-0.4..0.4))
            .collect();
        let adv: Vec<f32> = (0..b).map(|_| rng.random_range(-1.5..1.5)).collect();
        let returns: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
        let old_values: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
        let cfg = LossConfig {
            clip: 0.2,
            clip_value_loss,
            ent_coef: 0.05,
            vf_coef: 0.5,
        };

        // burn: the loss exactly as ppo::update builds it
        let eval = policy.evaluate(jsae_nn::tensor2(x.clone(), b, input, &device), &actions);
        let log_ratio = eval.logp - jsae_nn::tensor1(old_logp.clone(), &device);
        let pg = clipped_surrogate_loss(log_ratio, jsae_nn::tensor1(adv.clone(), &device), 0.2);
        let ret = jsae_nn::tensor1(returns.clone(), &device);
        let v_loss = if clip_value_loss {
            let old = jsae_nn::tensor1(old_values.clone(), &device);
            let unclipped = (eval.value.clone() - ret.clone()).square();
            let clipped_v = old.clone() + (eval.value - old).clamp(-0.2, 0.2);
            let clipped = (clipped_v - ret).square();
            unclipped.max_pair(clipped).mean().mul_scalar(0.5)
        } else {
            (eval.value - ret).square().mean().mul_scalar(0.5)
        };
        let loss: Tensor<1> = pg - eval.entropy.mean().mul_scalar(0.05) + v_loss.mul_scalar(0.5);
        let burn_loss = jsae_nn::to_vec(loss.clone())[0];
        let grads = loss.backward();

        let host = HostPolicy::from_policy(&policy);
        let x_host = Array2::from_shape_vec((b, input), x).expect("shape");
        let (continuous, discrete) = match &actions {
            ActionBatch::Continuous { data, .. } => (data.as_slice(), &[][..]),
            ActionBatch::Discrete(a) => (&[][..], a.as_slice()),
        };
        let mb = HostMinibatch {
            x: x_host.view(),
            continuous,
            discrete,
            old_logp: &old_logp,
            adv: &adv,
            returns: &returns,
            old_values: &old_values,
        };
        let (parts, g) = host.loss_and_grads(&mb, cfg);
        let what = format!("{head:?} tanh_mean {tanh_mean} clip_value {clip_value_loss}");
        close(&[parts.total], &[burn_loss], &format!("{what}: loss"));

        let (actor, critic, log_std) = policy.parts();
        for (name, mlp, host_grads) in [("actor", actor, &g.actor), ("critic", critic, &g.critic)] {
            for (i, layer) in mlp.layers().iter().enumerate() {
                let gw = layer.weight.val().grad(&grads).map(jsae_nn::to_vec);
                let gw = gw.unwrap_or_else(|| vec![0.0; host_grads.w[i].len()]);
                close(
                    &host_grads.w[i].iter().copied().collect::<Vec<_>>(),
                    &gw,
                    &format!("{what}: {name} weight {i}"),
                );
                let bias = layer.bias.as_ref().expect("biases");
                let gb = bias.val().grad(&grads).map(jsae_nn::to_vec);
                let gb = gb.unwrap_or_else(|| vec![0.0; host_grads.b[i].len()]);
                close(
                    &host_grads.b[i].to_vec(),
                    &gb,
                    &format!("{what}: {name} bias {i}"),
                );
            }
        }
        if let PolicyHead::Gaussian { .. } = head {
            let gls = log_std
                .val()
                .grad(&grads)
                .map(jsae_nn::to_vec)
                .expect("log-std gradient");
            close(
                g.log_std.as_slice().expect("contiguous"),
                &gls,
                &format!("{what}: log_std"),
            );
        }
    }

    #[test]
    fn gaussian_loss_and_gradients_equal_burn_autodiff() {
        for tanh_mean in [true, false] {
            for clip_value_loss in [false, true] {
                check(PolicyHead::Gaussian { dim: 3 }, tanh_mean, clip_value_loss);
            }
        }
    }

    #[test]
    fn categorical_loss_and_gradients_equal_burn_autodiff() {
        for clip_value_loss in [false, true] {
            check(PolicyHead::Categorical { n: 11 }, false, clip_value_loss);
        }
    }
}
