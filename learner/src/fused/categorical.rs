//! The categorical head's per-sample terms: log-softmax, entropy, the clipped surrogate and
//! the gradient at every logit. With hundreds to thousands of logits per sample this is as
//! much work as the output layer's products, so the rows are shared between rayon's threads
//! and each part is compiled for the widest vector instructions the CPU has (pulp's
//! dispatch, detected at run time; rounding is unchanged, as nothing is contracted).

use jsae_nn::host::math;

use super::loss::surrogate;
use super::{HostMinibatch, LossConfig};

/// Logits per part below which the rows are not split between threads.
const SPLIT: usize = 32 * 1024;

/// The surrogate's sum and the entropy's sum over the minibatch's samples, from the logits
/// `out` (`[b, n]` row-major); writes the loss's gradient at the logits into `d_out` and
/// each sample's `logp - old_logp` into `log_ratio` (resized to `b`).
pub(super) fn rows(
    out: &[f32],
    d_out: &mut [f32],
    n: usize,
    mb: &HostMinibatch<'_>,
    cfg: LossConfig,
    log_ratio: &mut Vec<f32>,
) -> (f32, f32) {
    let b = out.len() / n.max(1);
    log_ratio.resize(b, 0.0);
    let bf = b.max(1) as f32;
    let parts = rayon::current_num_threads().min(out.len() / SPLIT).max(1);
    let per = b.div_ceil(parts).max(1);
    let ctx = Rows { mb, cfg, n, bf };
    let arch = pulp::Arch::new();
    if parts == 1 {
        return arch.dispatch(Part {
            ctx: &ctx,
            first: 0,
            out,
            d_out,
            log_ratio,
        });
    }
    let mut pieces: Vec<_> = out
        .chunks(per * n)
        .zip(d_out.chunks_mut(per * n))
        .zip(log_ratio.chunks_mut(per))
        .enumerate()
        .collect();
    use rayon::prelude::*;
    // one sum per part, added in order: the same bits whichever thread took which part
    let sums: Vec<(f32, f32)> = pieces
        .par_iter_mut()
        .map(|(i, ((out, d_out), log_ratio))| {
            arch.dispatch(Part {
                ctx: &ctx,
                first: *i * per,
                out,
                d_out,
                log_ratio,
            })
        })
        .collect();
    sums.iter()
        .fold((0.0, 0.0), |acc, s| (acc.0 + s.0, acc.1 + s.1))
}

/// Samples `first..` of the minibatch (as many as `log_ratio` holds).
struct Part<'a, 'b, 'c> {
    ctx: &'a Rows<'b, 'c>,
    first: usize,
    out: &'a [f32],
    d_out: &'a mut [f32],
    log_ratio: &'a mut [f32],
}

impl pulp::WithSimd for Part<'_, '_, '_> {
    type Output = (f32, f32);

    /// Inlined whole into pulp's function for the instruction set, so its loops are
    /// vectorised for it.
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> (f32, f32) {
        self.ctx
            .run(self.first, self.out, self.d_out, self.log_ratio)
    }
}

/// What every part reads.
struct Rows<'a, 'b> {
    mb: &'a HostMinibatch<'b>,
    cfg: LossConfig,
    n: usize,
    /// The minibatch's size: the surrogate and the entropy are means over it.
    bf: f32,
}

impl Rows<'_, '_> {
    /// Samples `first..` (as many as `log_ratio` holds).
    #[inline(always)]
    fn run(
        &self,
        first: usize,
        out: &[f32],
        d_out: &mut [f32],
        log_ratio: &mut [f32],
    ) -> (f32, f32) {
        let (mut pg, mut ent_sum) = (0.0, 0.0);
        let ent = self.cfg.ent_coef / self.bf;
        for (k, ((o, d), lr_out)) in out
            .chunks_exact(self.n)
            .zip(d_out.chunks_exact_mut(self.n))
            .zip(log_ratio.iter_mut())
            .enumerate()
        {
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
        }
        (pg, ent_sum)
    }
}
