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

/// What [`HostAdam`] carries from one step to the next: the step count and both moments of
/// every parameter slice (a checkpoint saves it, so that a restarted learner steps exactly as
/// the one that stopped would have).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AdamMoments {
    /// Steps taken (the bias corrections' exponent).
    pub time: i32,
    /// First moments, one list per parameter slice.
    pub moment_1: Vec<Vec<f32>>,
    /// Second moments, likewise.
    pub moment_2: Vec<Vec<f32>>,
}

impl HostAdam {
    /// The state to save.
    pub fn moments(&self) -> AdamMoments {
        AdamMoments {
            time: self.time,
            moment_1: self.moment_1.clone(),
            moment_2: self.moment_2.clone(),
        }
    }

    /// Continues from saved state (the betas and epsilon stay this optimiser's).
    pub fn set_moments(&mut self, saved: AdamMoments) {
        self.time = saved.time;
        self.moment_1 = saved.moment_1;
        self.moment_2 = saved.moment_2;
    }

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
        self.step_rows(lr, grad_scale, params, grads, &[]);
    }

    /// [`Self::step`], where slice `i` with `rows[i]` given is stepped only in those rows
    /// (the "lazy" Adam of sparse embeddings: a row no minibatch touches keeps its value and
    /// its moments, where dense Adam would go on moving it by its decaying momentum). Its
    /// gradient is read in those rows only. A missing or `None` entry steps the whole slice.
    pub fn step_rows(
        &mut self,
        lr: f32,
        grad_scale: f32,
        params: &mut [&mut [f32]],
        grads: &[&[f32]],
        rows: &[Option<Rows<'_>>],
    ) {
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
        for (i, (((p, g), m), v)) in params
            .iter_mut()
            .zip(grads)
            .zip(&mut self.moment_1)
            .zip(&mut self.moment_2)
            .enumerate()
        {
            if m.len() != p.len() {
                *m = vec![0.0; p.len()];
                *v = vec![0.0; p.len()];
            }
            match rows.get(i).copied().flatten() {
                Some(r) => pieces.extend(
                    r.of_mut(p)
                        .into_iter()
                        .zip(r.of(g))
                        .zip(r.of_mut(m))
                        .zip(r.of_mut(v)),
                ),
                None => pieces.extend(
                    p.chunks_mut(PIECE)
                        .zip(g.chunks(PIECE))
                        .zip(m.chunks_mut(PIECE))
                        .zip(v.chunks_mut(PIECE)),
                ),
            }
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

/// The rows of a row-major `[_, width]` slice that a lazy step reads and writes
/// ([`HostAdam::step_rows`], [`global_norm_rows`], [`zero_rows`]).
#[derive(Debug, Clone, Copy)]
pub struct Rows<'a> {
    /// Values per row.
    pub width: usize,
    /// Row indices, ascending, without repeats.
    pub rows: &'a [u32],
}

impl Rows<'_> {
    /// The rows of `s`.
    ///
    /// # Panics
    /// When a row is past the end of `s`.
    fn of(self, s: &[f32]) -> Vec<&[f32]> {
        let w = self.width;
        self.rows
            .iter()
            .map(|&r| &s[r as usize * w..(r as usize + 1) * w])
            .collect()
    }

    /// The rows of `s`, mutable (disjoint borrows, taken in ascending order).
    ///
    /// # Panics
    /// When the rows are not ascending or a row is past the end of `s`.
    fn of_mut(self, s: &mut [f32]) -> Vec<&mut [f32]> {
        let w = self.width;
        let mut out = Vec::with_capacity(self.rows.len());
        let (mut rest, mut at) = (s, 0usize);
        for &r in self.rows {
            let r = r as usize;
            let (_, tail) = std::mem::take(&mut rest).split_at_mut((r - at) * w);
            let (row, tail) = tail.split_at_mut(w);
            out.push(row);
            (rest, at) = (tail, r + 1);
        }
        out
    }
}

/// [`global_norm`], reading slice `i` only in `rows[i]` where given (the others must be
/// zero there, as [`HostAdam::step_rows`]'s callers keep them).
pub fn global_norm_rows(grads: &[&[f32]], rows: &[Option<Rows<'_>>]) -> f32 {
    let mut pieces: Vec<&[f32]> = Vec::new();
    for (i, g) in grads.iter().enumerate() {
        match rows.get(i).copied().flatten() {
            Some(r) => pieces.extend(r.of(g)),
            None => pieces.push(g),
        }
    }
    global_norm(&pieces)
}

/// Sets `rows` of `s` to zero.
pub fn zero_rows(s: &mut [f32], rows: Rows<'_>) {
    for row in rows.of_mut(s) {
        row.fill(0.0);
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
    fn lazy_steps_move_only_the_rows_given_and_equal_dense_steps_on_them() {
        // [4, 3] weights and a plain slice; rows 1 and 3 touched every step
        let p0: Vec<f32> = (0..12).map(|i| (i as f32 * 0.7).sin()).collect();
        let q0 = vec![0.5f32, -0.25];
        let touched = [1u32, 3];
        let rows = [Some(Rows {
            width: 3,
            rows: &touched,
        })];
        let (mut lazy, mut dense) = (HostAdam::new(1e-5), HostAdam::new(1e-5));
        let (mut pl, mut ql, mut pd, mut qd) = (p0.clone(), q0.clone(), p0.clone(), q0.clone());
        for step in 1..4 {
            let g: Vec<f32> = (0..12)
                .map(|i| {
                    if [1, 3].contains(&(i / 3)) {
                        (i * step) as f32 * 0.1 - 0.4
                    } else {
                        0.0
                    }
                })
                .collect();
            let gq = vec![0.3 * step as f32, -0.1];
            let norm = global_norm_rows(&[&g, &gq], &rows);
            assert!((norm - global_norm(&[&g, &gq])).abs() < 1e-6);
            lazy.step_rows(1e-2, 0.5, &mut [&mut pl, &mut ql], &[&g, &gq], &rows);
            dense.step(1e-2, 0.5, &mut [&mut pd, &mut qd], &[&g, &gq]);
        }
        // untouched rows are where they started; the touched ones and the plain slice equal
        // dense Adam's (whose untouched rows never saw a gradient, so stay too)
        assert_eq!(&pl[0..3], &p0[0..3]);
        assert_eq!(&pl[6..9], &p0[6..9]);
        assert_eq!(pl, pd);
        assert_eq!(ql, qd);
        let mut g = vec![1.0f32; 12];
        zero_rows(&mut g, rows[0].expect("rows"));
        assert_eq!(g.iter().filter(|&&v| v == 0.0).count(), 6);
        assert_eq!(&g[3..6], &[0.0; 3]);
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
