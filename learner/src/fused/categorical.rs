//! The categorical head's per-sample terms: log-softmax, entropy, the clipped surrogate and
//! the gradient at every logit. With hundreds to thousands of logits per sample this is as
//! much work as the output layer's products, so the rows are shared between rayon's threads
//! and each part is compiled for the widest vector instructions the CPU has (pulp's
//! dispatch, detected at run time; rounding is unchanged, as nothing is contracted). The
//! output layer's bias is added here and its gradient summed here
//! ([`jsae_nn::OutputBias::ByCaller`]), each row while it is in cache, instead of in two more
//! passes over all logits.

use jsae_nn::host::math;

use super::{HostMinibatch, LossConfig, surrogate};

/// Logits per part below which the rows are not split between threads.
const SPLIT: usize = 32 * 1024;

/// The output layer's bias and the buffer of its gradient.
pub(super) struct Bias<'a> {
    /// `[n]`, added to every row of logits.
    pub(super) value: &'a [f32],
    /// `[n]`, written: the sum over rows of the gradient at the logits.
    pub(super) grad: &'a mut [f32],
}

/// The surrogate's, the entropy's and the next-purchase cross-entropy's sums over the
/// minibatch's samples, from the output
/// layer's products `out` (`[b, n]` row-major, the bias added here in place: the logits);
/// writes the loss's gradient at the logits into `d_out` (each sample's terms divided by
/// `bf`, the whole minibatch's size), its sum over rows into `bias.grad`, and each sample's
/// `logp - old_logp` into `log_ratio` (resized to `b`).
pub(super) fn rows(
    out: &mut [f32],
    d_out: &mut [f32],
    bias: Bias<'_>,
    mb: &HostMinibatch<'_>,
    cfg: LossConfig,
    bf: f32,
    log_ratio: &mut Vec<f32>,
) -> (f32, f32, f32) {
    let n = bias.value.len();
    let b = out.len() / n.max(1);
    log_ratio.resize(b, 0.0);
    let parts = rayon::current_num_threads().min(out.len() / SPLIT).max(1);
    let per = b.div_ceil(parts).max(1);
    let ctx = Rows {
        mb,
        cfg,
        bias: bias.value,
        bf,
    };
    let arch = pulp::Arch::new();
    bias.grad.fill(0.0);
    if parts == 1 {
        return arch.dispatch(Part {
            ctx: &ctx,
            first: 0,
            out,
            d_out,
            log_ratio,
            d_bias: bias.grad,
        });
    }
    let mut pieces: Vec<_> = out
        .chunks_mut(per * n)
        .zip(d_out.chunks_mut(per * n))
        .zip(log_ratio.chunks_mut(per))
        .enumerate()
        .collect();
    use rayon::prelude::*;
    // one sum per part, added in order: the same bits whichever thread took which part
    let sums: Vec<((f32, f32, f32), Vec<f32>)> = pieces
        .par_iter_mut()
        .map(|(i, ((out, d_out), log_ratio))| {
            let mut d_bias = vec![0.0; n];
            let sums = arch.dispatch(Part {
                ctx: &ctx,
                first: *i * per,
                out,
                d_out,
                log_ratio,
                d_bias: &mut d_bias,
            });
            (sums, d_bias)
        })
        .collect();
    let mut totals = (0.0, 0.0, 0.0);
    for (s, d_bias) in &sums {
        totals = (totals.0 + s.0, totals.1 + s.1, totals.2 + s.2);
        for (g, &d) in bias.grad.iter_mut().zip(d_bias) {
            *g += d;
        }
    }
    totals
}

/// Samples `first..` of the minibatch (as many as `log_ratio` holds); their gradients at
/// the logits are added to `d_bias`.
struct Part<'a, 'b, 'c> {
    ctx: &'a Rows<'b, 'c>,
    first: usize,
    out: &'a mut [f32],
    d_out: &'a mut [f32],
    log_ratio: &'a mut [f32],
    d_bias: &'a mut [f32],
}

impl pulp::WithSimd for Part<'_, '_, '_> {
    type Output = (f32, f32, f32);

    /// Inlined whole into pulp's function for the instruction set, so its loops are
    /// vectorised for it.
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> (f32, f32, f32) {
        self.ctx.run(
            self.first,
            self.out,
            self.d_out,
            self.log_ratio,
            self.d_bias,
        )
    }
}

/// What every part reads.
struct Rows<'a, 'b> {
    mb: &'a HostMinibatch<'b>,
    cfg: LossConfig,
    /// The output layer's bias, `[n]`.
    bias: &'a [f32],
    /// The whole minibatch's size: the surrogate and the entropy are means over it.
    bf: f32,
}

impl Rows<'_, '_> {
    /// Samples `first..` (as many as `log_ratio` holds).
    #[inline(always)]
    fn run(
        &self,
        first: usize,
        out: &mut [f32],
        d_out: &mut [f32],
        log_ratio: &mut [f32],
        d_bias: &mut [f32],
    ) -> (f32, f32, f32) {
        let (mut pg, mut ent_sum, mut nll_sum) = (0.0, 0.0, 0.0);
        let ent = self.cfg.ent_coef / self.bf;
        let next = self.cfg.next_purchase_coef / self.bf;
        let targets = if next > 0.0 {
            self.mb.next_purchase
        } else {
            &[]
        };
        let n = self.bias.len().max(1);
        for (k, ((o, d), lr_out)) in out
            .chunks_exact_mut(n)
            .zip(d_out.chunks_exact_mut(n))
            .zip(log_ratio.iter_mut())
            .enumerate()
        {
            for (o, &b) in o.iter_mut().zip(self.bias) {
                *o += b;
            }
            let o = &*o;
            let i = first + k;
            let max = math::max(o);
            // unnormalised probabilities into d first
            let z = math::exp_shifted(d, o, max);
            let log_z = max + z.ln();
            let inv_z = 1.0 / z;
            let h = -inv_z * math::dot_shifted(d, o, log_z);
            ent_sum += h;
            let a = self.mb.discrete[i] as usize;
            let lr = o[a] - log_z - self.mb.old_logp[i];
            *lr_out = lr;
            let (loss, dpg) = surrogate(lr, self.mb.adv[i], self.cfg.clip);
            pg += loss;
            let dpg = dpg / self.bf;
            // d loss / d o_k = dpg (1[k=a] - p_k) + ent_coef p_k (logp_k + h) / b
            for (dk, &ok) in d.iter_mut().zip(o) {
                let pk = *dk * inv_z;
                *dk = -dpg * pk + ent * pk * (ok - log_z + h);
            }
            d[a] += dpg;
            // the next purchase's cross-entropy: d/d o_k = coef (p_k - 1[k=t]) / b
            if let Some(&t) = targets.get(i).filter(|&&t| (t as usize) < n) {
                let t = t as usize;
                nll_sum += log_z - o[t];
                for (dk, &ok) in d.iter_mut().zip(o) {
                    *dk += next * (ok - log_z).exp();
                }
                d[t] -= next;
            }
            for (g, &dk) in d_bias.iter_mut().zip(d.iter()) {
                *g += dk;
            }
        }
        (pg, ent_sum, nll_sum)
    }
}
