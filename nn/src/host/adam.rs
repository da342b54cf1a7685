//! Adam and global gradient-norm clipping over flat host parameters, with burn's arithmetic:
//! `m = b1 m + (1 - b1) g`, `v = b2 v + (1 - b2) g^2`, and
//! `p -= lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)` (as
//! `burn::optim::Adam`, no weight decay); clipping as [`crate::clip_global_grad_norm`], its
//! factor applied to each gradient as Adam reads it (one pass over the parameters, not two).
//! Both split the parameters into pieces that rayon's threads share.

use rayon::prelude::*;

/// Elements per piece of work shared between threads.
const PIECE: usize = 16 * 1024;
/// Pieces below which one thread does all (waking another costs more than it saves).
const PARALLEL_PIECES: usize = 8;

/// Adam's moments for a list of parameter slices (shapes fixed by the first step).
#[derive(Debug, Clone)]
pub struct HostAdam {
    beta_1: f32,
    beta_2: f32,
    epsilon: f32,
    time: i32,
    moment_1: Vec<Vec<f32>>,
    moment_2: Vec<Vec<f32>>,
}

impl HostAdam {
    /// Adam with betas 0.9 / 0.999 and the given epsilon.
    pub fn new(epsilon: f32) -> Self {
        Self {
            beta_1: 0.9,
            beta_2: 0.999,
            epsilon,
            time: 0,
            moment_1: Vec::new(),
            moment_2: Vec::new(),
        }
    }

    /// One step: `params[i] -= lr * adam(grad_scale * grads[i])` (`grad_scale` from
    /// [`clip_scale`], or 1). The lists must keep their order and shapes from step to step
    /// (a shape change restarts the moments of that slice).
    pub fn step(&mut self, lr: f32, grad_scale: f32, params: &mut [&mut [f32]], grads: &[&[f32]]) {
        if self.moment_1.len() != params.len() {
            self.moment_1 = params.iter().map(|p| vec![0.0; p.len()]).collect();
            self.moment_2 = self.moment_1.clone();
        }
        self.time += 1;
        let (b1, b2) = (self.beta_1, self.beta_2);
        let bias_1 = 1.0 - b1.powi(self.time);
        let bias_2_sqrt = (1.0 - b2.powi(self.time)).sqrt();
        // burn's form: m * (sqrt(bc2) / bc1) / (sqrt(v) + eps * sqrt(bc2))
        let factor = bias_2_sqrt / bias_1;
        let eps = self.epsilon * bias_2_sqrt;
        let mut pieces = Vec::new();
        for (((p, g), m), v) in params
            .iter_mut()
            .zip(grads)
            .zip(&mut self.moment_1)
            .zip(&mut self.moment_2)
        {
            if m.len() != p.len() {
                *m = vec![0.0; p.len()];
                *v = vec![0.0; p.len()];
            }
            pieces.extend(
                p.chunks_mut(PIECE)
                    .zip(g.chunks(PIECE))
                    .zip(m.chunks_mut(PIECE))
                    .zip(v.chunks_mut(PIECE)),
            );
        }
        let step = AdamPiece {
            b1,
            b2,
            lr,
            factor,
            eps,
            grad_scale,
        };
        let arch = pulp::Arch::new();
        if pieces.len() < PARALLEL_PIECES {
            for (((p, g), m), v) in pieces {
                arch.dispatch(step.on(p, g, m, v));
            }
        } else {
            pieces
                .into_par_iter()
                .for_each(|(((p, g), m), v)| arch.dispatch(step.on(p, g, m, v)));
        }
    }
}

/// One Adam step's constants.
#[derive(Debug, Clone, Copy)]
struct AdamPiece {
    b1: f32,
    b2: f32,
    lr: f32,
    factor: f32,
    eps: f32,
    grad_scale: f32,
}

impl AdamPiece {
    fn on<'a>(
        self,
        p: &'a mut [f32],
        g: &'a [f32],
        m: &'a mut [f32],
        v: &'a mut [f32],
    ) -> AdamOn<'a> {
        AdamOn {
            c: self,
            p,
            g,
            m,
            v,
        }
    }
}

/// The step on one piece, inlined whole into pulp's function for the CPU's vector
/// instructions (rounding unchanged: nothing is contracted).
struct AdamOn<'a> {
    c: AdamPiece,
    p: &'a mut [f32],
    g: &'a [f32],
    m: &'a mut [f32],
    v: &'a mut [f32],
}

impl pulp::WithSimd for AdamOn<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let c = self.c;
        let (b1, b2, lr, factor, eps) = (c.b1, c.b2, c.lr, c.factor, c.eps);
        for (((p, &g), m), v) in self
            .p
            .iter_mut()
            .zip(self.g)
            .zip(self.m.iter_mut())
            .zip(self.v.iter_mut())
        {
            let g = g * c.grad_scale;
            *m = b1 * *m + (1.0 - b1) * g;
            *v = b2 * *v + (1.0 - b2) * g * g;
            *p -= lr * (*m * factor) / (v.sqrt() + eps);
        }
    }
}

/// `total[i] += part[i]` for every slice (the same shapes; an empty `part[i]` adds nothing),
/// shared between rayon's threads: gradients of a minibatch's parts added into the first
/// part's.
pub fn add_gradients(total: &mut [&mut [f32]], part: &[&[f32]]) {
    let pieces: Vec<(&mut [f32], &[f32])> = total
        .iter_mut()
        .zip(part)
        .flat_map(|(t, p)| t.chunks_mut(PIECE).zip(p.chunks(PIECE)))
        .collect();
    let add = |(t, p): (&mut [f32], &[f32])| {
        for (t, &p) in t.iter_mut().zip(p) {
            *t += p;
        }
    };
    if pieces.len() < PARALLEL_PIECES {
        pieces.into_iter().for_each(add);
    } else {
        pieces.into_par_iter().for_each(add);
    }
}

/// The joint L2 norm of all gradients.
pub fn global_norm(grads: &[&[f32]]) -> f32 {
    let pieces: Vec<&[f32]> = grads.iter().flat_map(|g| g.chunks(PIECE)).collect();
    // one sum per piece, added in order: the same bits whichever thread took which piece
    let sq: f64 = if pieces.len() < PARALLEL_PIECES {
        pieces.into_iter().map(squares).sum()
    } else {
        let sums: Vec<f64> = pieces.into_par_iter().map(squares).collect();
        sums.iter().sum()
    };
    sq.sqrt() as f32
}

/// The sum of squares of one piece: f32 lanes within it (at most 16k values), f64 across.
fn squares(piece: &[f32]) -> f64 {
    let mut acc = [0.0f32; 8];
    let chunks = piece.chunks_exact(8);
    let tail: f32 = chunks.remainder().iter().map(|&v| v * v).sum();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a += v * v;
        }
    }
    f64::from(acc.iter().sum::<f32>() + tail)
}

/// The factor that scales gradients of joint norm `norm` to at most `max_norm` (1 when
/// they are within it, or when the norm is not finite).
pub fn clip_scale(norm: f32, max_norm: f32) -> f32 {
    if norm > max_norm && norm.is_finite() {
        max_norm / (norm + 1e-6)
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    //! Against burn's Adam and clipping on the same parameters and gradients.

    use super::*;
    use crate::{BurnDevice, DeviceKind};
    use burn::module::{Module, Param};
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::Tensor;

    #[derive(Module, Debug)]
    struct Two {
        a: Param<Tensor<1>>,
        b: Param<Tensor<1>>,
    }

    #[test]
    fn adam_steps_and_clipping_equal_burns() {
        let device = DeviceKind::Flex.train_device();
        let a0: Vec<f32> = (0..7).map(|i| (i as f32 * 0.37).sin()).collect();
        let b0: Vec<f32> = (0..3).map(|i| (i as f32 * 1.3).cos()).collect();
        let mut module = Two {
            a: Param::from_tensor(crate::tensor1(a0.clone(), &device)),
            b: Param::from_tensor(crate::tensor1(b0.clone(), &device)),
        };
        let mut optim = AdamConfig::new().with_epsilon(1e-5).init();
        let mut host = HostAdam::new(1e-5);
        let (mut ha, mut hb) = (a0, b0);
        for step in 0..5 {
            // loss = sum(c_a * a^3) + sum(c_b * b^2): gradients 3 c_a a^2 and 2 c_b b
            let scale = 1.0 + step as f32;
            let ca: Vec<f32> = (0..7).map(|i| scale * (i as f32 - 3.0)).collect();
            let cb: Vec<f32> = (0..3).map(|i| scale * (1.0 - i as f32)).collect();
            let loss = (module.a.val().powi_scalar(3) * crate::tensor1(ca.clone(), &device)).sum()
                + (module.b.val().powi_scalar(2) * crate::tensor1(cb.clone(), &device)).sum();
            let mut grads = GradientsParams::from_grads(loss.backward(), &module);
            let burn_norm = crate::clip_global_grad_norm(&module, &mut grads, 1.0);
            module = optim.step(1e-2, module, grads);

            let ga: Vec<f32> = ha.iter().zip(&ca).map(|(a, c)| 3.0 * c * a * a).collect();
            let gb: Vec<f32> = hb.iter().zip(&cb).map(|(b, c)| 2.0 * c * b).collect();
            let norm = global_norm(&[&ga, &gb]);
            host.step(
                1e-2,
                clip_scale(norm, 1.0),
                &mut [&mut ha, &mut hb],
                &[&ga, &gb],
            );
            assert!(
                (norm - burn_norm).abs() <= 1e-5 * burn_norm,
                "{norm} vs {burn_norm}"
            );
            for (h, b) in ha.iter().zip(crate::to_vec(module.a.val())) {
                assert!((h - b).abs() < 1e-6, "step {step}: a {h} vs {b}");
            }
            for (h, b) in hb.iter().zip(crate::to_vec(module.b.val())) {
                assert!((h - b).abs() < 1e-6, "step {step}: b {h} vs {b}");
            }
        }
    }
}
