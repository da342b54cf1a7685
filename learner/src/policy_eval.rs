//! What PPO's losses need of the policy beyond acting ([`PolicyEval`]): the critic's values
//! and the log-probabilities and entropies of given actions, through burn (with gradients on
//! an autodiff device). The acting half is `jsae_agent::Policy`'s.

use burn::tensor::activation::log_softmax;
use burn::tensor::{Int, Tensor, TensorData};
use jsae_agent::Policy;
use jsae_agent::policy::{HALF_LOG_2PI, PolicyHead};
use jsae_nn as nn;
use jsae_wire::ActionBatch;

/// What training needs per minibatch.
#[derive(Debug)]
pub struct Evaluation {
    /// Log-probability of the given actions, `[batch]`.
    pub logp: Tensor<1>,
    /// Entropy per sample, `[batch]`.
    pub entropy: Tensor<1>,
    /// `V(x)`, `[batch]`.
    pub value: Tensor<1>,
}

/// The training half of the policy.
pub trait PolicyEval {
    /// `V(x)`: `[batch, input] -> [batch]` (through burn: a policy without the pair feature,
    /// which only the fused update's host passes build).
    fn value(&self, x: Tensor<2>) -> Tensor<1>;

    /// Log-probabilities, entropies and values of `actions` at `x` (with gradients on an
    /// autodiff device; a policy without the pair feature, as [`Self::value`]).
    fn evaluate(&self, x: Tensor<2>, actions: &ActionBatch) -> Evaluation;
}

impl PolicyEval for Policy {
    fn value(&self, x: Tensor<2>) -> Tensor<1> {
        let v = self.parts().1.forward(self.network_input(x));
        let [b, _] = v.dims();
        v.reshape([b])
    }

    fn evaluate(&self, x: Tensor<2>, actions: &ActionBatch) -> Evaluation {
        let value = self.value(x.clone());
        let out = self.actor_out(x); // [batch, outputs]
        let [batch, width] = out.dims();
        let (logp, entropy) = match (self.head(), actions) {
            (PolicyHead::Gaussian { dim }, ActionBatch::Continuous { data, .. }) => {
                let a = nn::tensor2(data.clone(), batch, dim, self.device());
                let log_std = self.log_std().reshape([1, dim]); // [1, dim]
                let z = (a - out) / log_std.clone().exp();
                let logp = (z.square().mul_scalar(-0.5) - log_std.clone())
                    .sum_dim(1)
                    .reshape([batch])
                    .sub_scalar(HALF_LOG_2PI * dim as f32);
                let ent = log_std
                    .clamp_max(self.entropy_log_std_max())
                    .sum_dim(1)
                    .add_scalar((0.5 + HALF_LOG_2PI) * dim as f32);
                (
                    logp,
                    Tensor::<1>::ones([batch], self.device()).mul(ent.reshape([1])),
                )
            }
            (PolicyHead::Categorical { .. }, ActionBatch::Discrete(a)) => {
                let lp = log_softmax(out, 1); // [batch, n]
                let idx: Vec<i64> = a.iter().map(|&v| i64::from(v)).collect();
                let idx =
                    Tensor::<2, Int>::from_data(TensorData::new(idx, [batch, 1]), self.device());
                let logp = lp.clone().gather(1, idx).reshape([batch]);
                let ent = (lp.clone().exp() * lp).sum_dim(1).reshape([batch]).neg();
                (logp, ent)
            }
            _ => {
                let _ = width;
                let zeros = Tensor::<1>::zeros([batch], self.device());
                (zeros.clone(), zeros)
            }
        };
        Evaluation {
            logp,
            entropy,
            value,
        }
    }
}
