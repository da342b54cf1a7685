//! Training on the host without a tensor graph: an MLP's forward and backward pass over
//! preallocated buffers with the dense products on a GEMM kernel (`dense`: the gemm crate's,
//! AVX-512 where the CPU has it),
//! vectorisable `exp`/`tanh` (`math`), and Adam with global gradient-norm clipping (`adam`),
//! equal to burn's. At minibatch sizes like PPO's 64 a graph of small tensor operations
//! costs far more in per-operation overhead than in arithmetic; these do the arithmetic only.
//!
//! The weights are copies of burn modules' parameters ([`HostMlp::from_burn`]) written back
//! with [`crate::Mlp::set_from_host`]: the burn module stays the one model definition.

mod adam;
mod dense;
mod elementwise;
pub mod math;
mod sparse;

use ndarray::{Array1, Array2, ArrayView2, ArrayViewMut2, Axis};

pub use adam::{
    AdamMoments, HostAdam, Rows, add_gradients, clip_scale, global_norm, global_norm_rows,
    zero_rows,
};
pub use dense::product;
pub use sparse::{HostInput, PairCross, SparseRows, pair_bucket};

/// An MLP's weights on the host, tanh between layers, none after the last. The first layer's
/// weights are `[in, out]` (burn's layout: a one-hot input picks weight rows); every later
/// layer's are `[out, in]`, transposed, the layout in which the forward product, the weight
/// gradient and the input gradient all run at the kernel's full speed (with `[in, out]` the
/// input gradient reads the weights across rows and runs at half speed on wide layers).
/// [`Self::weight`] reads any layer in burn's layout. `b[i]` is `[out]`. The input-to-output
/// path ([`crate::MlpConfig::skip`]), where there is one, is `[in, out]` like the first layer.
#[derive(Debug, Clone, PartialEq)]
pub struct HostMlp {
    /// Weights per layer: `[in, out]` for the first, `[out, in]` for the others.
    pub w: Vec<Array2<f32>>,
    /// Biases per layer, `[out]`.
    pub b: Vec<Array1<f32>>,
    /// The input-to-output weights, `[in, out]`, if any.
    pub skip: Option<Array2<f32>>,
}

/// One MLP pass's buffers, kept between minibatches.
#[derive(Debug, Clone, Default)]
pub struct MlpWork {
    /// Each layer's output (after tanh for hidden layers).
    acts: Vec<Array2<f32>>,
    /// The loss's gradient at each layer's pre-activation output.
    delta: Vec<Array2<f32>>,
}

/// `a` as a `rows x cols` array, reallocated only when the shape changes.
fn shaped(a: &mut Array2<f32>, rows: usize, cols: usize) {
    if a.dim() != (rows, cols) {
        *a = Array2::zeros((rows, cols));
    }
}

impl MlpWork {
    /// The output of the last [`HostMlp::forward`], `[batch, output]` (without the last
    /// layer's bias after [`HostMlp::forward_with`] with [`OutputBias::ByCaller`], until the
    /// caller adds it).
    pub fn output(&self) -> &Array2<f32> {
        &self.acts[self.acts.len() - 1]
    }

    /// The output (read) and the buffer of its gradient (written), together.
    pub fn output_and_grad(&mut self) -> (&Array2<f32>, &mut Array2<f32>) {
        let last = self.acts.len() - 1;
        (&self.acts[last], &mut self.delta[last])
    }

    /// The loss's gradient at the output (what the caller wrote), `[batch, output]`: with
    /// [`InputWeights::ByCaller`] the caller multiplies the inputs by it for the
    /// input-to-output path's weight gradient.
    pub fn output_grad(&self) -> &Array2<f32> {
        &self.delta[self.delta.len() - 1]
    }

    /// The loss's gradient at the first layer's output (before its tanh), after
    /// [`HostMlp::backward_with`]: with [`InputWeights::ByCaller`] the caller multiplies the
    /// inputs by it for the first layer's weight gradient.
    pub fn input_layer_grad(&self) -> &Array2<f32> {
        &self.delta[0]
    }

    /// The output (written: with [`OutputBias::ByCaller`] the caller adds the bias in place)
    /// and the buffer of its gradient, together.
    pub fn output_mut_and_grad(&mut self) -> (&mut Array2<f32>, &mut Array2<f32>) {
        let last = self.acts.len() - 1;
        (&mut self.acts[last], &mut self.delta[last])
    }
}

/// Who computes the weight gradients of the layers that read the input (the first, and the
/// input-to-output path where there is one). A minibatch split between threads has
/// one gradient per part; for one-hot inputs, whose first layer is thousands of rows of which
/// a minibatch touches a few hundred, each part's full-size gradient (zeroed, then added to the
/// others') costs more than adding each part's few rows into one gradient afterwards.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputWeights {
    /// [`HostMlp::backward_with`] writes it.
    InPass,
    /// It is left unwritten; the caller adds `x^T` [`MlpWork::input_layer_grad`] where it
    /// wants it.
    ByCaller,
    /// On one-hot (sparse) inputs, added into the gradient buffer's rows that the inputs pick
    /// instead of overwriting the whole buffer: the caller keeps every other row at zero
    /// (a lazy optimiser that reads and clears only the rows a minibatch touched; on a first
    /// layer of ~10^6 weights a pass over the whole buffer per minibatch costs more than
    /// the minibatch). Dense inputs are written as with [`Self::InPass`].
    Accumulate,
}

/// Who handles the last layer's bias. On a wide output (thousands of logits) a pass over it
/// costs as much as a product, so a caller that walks the output anyway (the softmax rows)
/// can add the bias and sum its gradient in that walk instead of two more passes here.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutputBias {
    /// [`HostMlp::forward_with`] adds it; [`HostMlp::backward_with`] sums its gradient.
    InPass,
    /// The forward pass leaves the output without it: the caller adds `b[last]` to every
    /// output row before reading it (so the output is the same), and writes the bias's
    /// gradient (the column sums of the output's gradient) into `grads.b[last]` itself.
    ByCaller,
}

impl HostMlp {
    /// A copy of `mlp`'s weights.
    pub fn from_burn(mlp: &crate::Mlp) -> Self {
        let mut w = Vec::new();
        let mut b = Vec::new();
        for layer in mlp.layers() {
            let burn_layout = burn_weight(layer);
            let cols = burn_layout.ncols();
            w.push(if w.is_empty() {
                burn_layout
            } else {
                burn_layout.t().as_standard_layout().into_owned()
            });
            let bias = layer
                .bias
                .as_ref()
                .map_or_else(|| vec![0.0; cols], |p| crate::to_vec(p.val()));
            b.push(Array1::from(bias));
        }
        let skip = mlp.skip().map(burn_weight);
        Self { w, b, skip }
    }

    /// Layer `i`'s weights (or weight gradients) in burn's layout, `[in, out]`.
    pub fn weight(&self, i: usize) -> ArrayView2<'_, f32> {
        if i == 0 {
            self.w[0].view()
        } else {
            self.w[i].t()
        }
    }

    /// Zeros in this MLP's shape (gradients, optimiser moments).
    pub fn zeros_like(&self) -> Self {
        Self {
            w: self.w.iter().map(|w| Array2::zeros(w.raw_dim())).collect(),
            b: self.b.iter().map(|b| Array1::zeros(b.raw_dim())).collect(),
            skip: self.skip.as_ref().map(|s| Array2::zeros(s.raw_dim())),
        }
    }

    /// Every parameter as a flat slice, weights and bias of each layer in turn, then the
    /// input-to-output weights (at [`Self::skip_slice`]) if there are any.
    pub fn slices(&self) -> Vec<&[f32]> {
        let mut out = Vec::with_capacity(2 * self.w.len() + 1);
        for (w, b) in self.w.iter().zip(&self.b) {
            out.push(w.as_slice().unwrap_or(&[]));
            out.push(b.as_slice().unwrap_or(&[]));
        }
        if let Some(skip) = &self.skip {
            out.push(skip.as_slice().unwrap_or(&[]));
        }
        out
    }

    /// Where the input-to-output weights are among [`Self::slices`], if there are any.
    pub fn skip_slice(&self) -> Option<usize> {
        self.skip.as_ref().map(|_| 2 * self.w.len())
    }

    /// Every parameter as a flat mutable slice, in the order of [`Self::slices`].
    pub fn slices_mut(&mut self) -> Vec<&mut [f32]> {
        let mut out = Vec::with_capacity(2 * self.w.len() + 1);
        for (w, b) in self.w.iter_mut().zip(&mut self.b) {
            out.push(w.as_slice_mut().unwrap_or(&mut []));
            out.push(b.as_slice_mut().unwrap_or(&mut []));
        }
        if let Some(skip) = &mut self.skip {
            out.push(skip.as_slice_mut().unwrap_or(&mut []));
        }
        out
    }

    /// Runs `x` (`[batch, input]`) through the layers into `work`; the output is
    /// [`MlpWork::output`].
    pub fn forward(&self, x: HostInput<'_>, work: &mut MlpWork) {
        self.forward_with(x, work, OutputBias::InPass);
    }

    /// [`Self::forward`], with the last layer's bias added here or left to the caller.
    pub fn forward_with(&self, x: HostInput<'_>, work: &mut MlpWork, output_bias: OutputBias) {
        let n = self.w.len();
        let rows = x.nrows();
        work.acts.resize_with(n, Default::default);
        work.delta.resize_with(n, Default::default);
        for i in 0..n {
            let cols = self.b[i].len();
            shaped(&mut work.acts[i], rows, cols);
            shaped(&mut work.delta[i], rows, cols);
            let (done, rest) = work.acts.split_at_mut(i);
            let out = &mut rest[0];
            match (i, x) {
                (0, HostInput::Dense(x)) => mat_mul(x, self.w[0].view(), out.view_mut()),
                (0, HostInput::Sparse(x)) => x.mul(&self.w[0], out),
                _ => mat_mul(done[i - 1].view(), self.w[i].t(), out.view_mut()),
            }
            if let (true, Some(skip)) = (i + 1 == n, &self.skip) {
                match x {
                    HostInput::Dense(x) => *out += &x.dot(skip),
                    HostInput::Sparse(x) => x.mul_add(skip, out),
                }
            }
            if i + 1 == n && output_bias == OutputBias::ByCaller {
                break;
            }
            let bias = self.b[i].as_slice().unwrap_or(&[]);
            let data = out.as_slice_mut().unwrap_or(&mut []);
            // tanh between layers, none after the last
            elementwise::add_bias(data, bias, i + 1 < n);
        }
    }

    /// The gradients of every weight and bias into `grads` (same shapes as `self`), from the
    /// gradient the caller wrote at [`MlpWork::output_and_grad`] after [`Self::forward`] on `x`.
    pub fn backward(&self, x: HostInput<'_>, work: &mut MlpWork, grads: &mut HostMlp) {
        self.backward_with(x, work, grads, OutputBias::InPass, InputWeights::InPass);
    }

    /// [`Self::backward`], with the last layer's bias gradient summed here or left as the
    /// caller wrote it (`output_bias` as given to [`Self::forward_with`]), and the first
    /// layer's weight gradient written here or left to the caller.
    pub fn backward_with(
        &self,
        x: HostInput<'_>,
        work: &mut MlpWork,
        grads: &mut HostMlp,
        output_bias: OutputBias,
        input_weights: InputWeights,
    ) {
        let last = self.w.len().saturating_sub(1);
        if let Some(g) = grads.skip.as_mut() {
            let delta = &work.delta[last];
            match (x, input_weights) {
                (_, InputWeights::ByCaller) => {}
                (HostInput::Dense(x), _) => mat_mul(x.t(), delta.view(), g.view_mut()),
                (HostInput::Sparse(x), InputWeights::Accumulate) => x.outer_add(delta, g),
                (HostInput::Sparse(x), _) => x.outer(delta, g),
            }
        }
        for i in (0..self.w.len()).rev() {
            let (lower, upper) = work.delta.split_at_mut(i);
            let delta = &upper[0];
            match (i, x) {
                (0, _) if input_weights == InputWeights::ByCaller => {}
                (0, HostInput::Dense(x)) => mat_mul(x.t(), delta.view(), grads.w[0].view_mut()),
                (0, HostInput::Sparse(x)) if input_weights == InputWeights::Accumulate => {
                    x.outer_add(delta, &mut grads.w[0])
                }
                (0, HostInput::Sparse(x)) => x.outer(delta, &mut grads.w[0]),
                // [out, in] = [out, rows] x [rows, in]
                _ => mat_mul(delta.t(), work.acts[i - 1].view(), grads.w[i].view_mut()),
            }
            match (delta.as_slice(), grads.b[i].as_slice_mut()) {
                _ if i == last && output_bias == OutputBias::ByCaller => {}
                (Some(d), Some(gb)) => elementwise::column_sums(d, gb),
                _ => grads.b[i].assign(&delta.sum_axis(Axis(0))),
            }
            if i > 0 {
                let below = &mut lower[i - 1];
                // [rows, in] = [rows, out] x [out, in]
                mat_mul(delta.view(), self.w[i].view(), below.view_mut());
                // through the tanh of layer i-1: d tanh = 1 - tanh^2
                let acts = &work.acts[i - 1];
                match (below.as_slice_mut(), acts.as_slice()) {
                    (Some(g), Some(a)) => elementwise::through_tanh(g, a),
                    _ => below.zip_mut_with(acts, |g, &a| *g *= 1.0 - a * a),
                }
            }
        }
    }
}

/// A burn layer's weights in its layout, `[in, out]`.
fn burn_weight(layer: &burn::nn::Linear) -> Array2<f32> {
    let weight = layer.weight.val();
    let [rows, cols] = weight.dims();
    Array2::from_shape_vec((rows, cols), crate::to_vec(weight))
        .unwrap_or_else(|_| Array2::zeros((rows, cols)))
}

/// FLOPs above which a product is split into parts run side by side (rayon's pool):
/// the wide output layers of categorical heads (512 to 4,096 logits) would otherwise keep
/// one core busy while the other, done with the small critic, waits.
const SPLIT_FLOPS: usize = 4_000_000;

/// `c = a b`, split along `c`'s longer side into as many parts as rayon has threads when
/// it is large (each part packs its own copy of the shared operand, so no more).
fn mat_mul(a: ArrayView2<'_, f32>, b: ArrayView2<'_, f32>, c: ArrayViewMut2<'_, f32>) {
    split_mat_mul(a, b, c, rayon::current_num_threads());
}

fn split_mat_mul(
    a: ArrayView2<'_, f32>,
    b: ArrayView2<'_, f32>,
    c: ArrayViewMut2<'_, f32>,
    parts: usize,
) {
    let (m, k, n) = (a.nrows(), a.ncols(), b.ncols());
    if parts < 2 || 2 * m * k * n < SPLIT_FLOPS || m.max(n) < 32 {
        dense::product(a, b, c);
        return;
    }
    let (left, right) = (parts / 2, parts - parts / 2);
    if n >= m {
        let at = n * left / parts;
        let (b1, b2) = b.split_at(Axis(1), at);
        let (c1, c2) = c.split_at(Axis(1), at);
        rayon::join(
            || split_mat_mul(a, b1, c1, left),
            || split_mat_mul(a, b2, c2, right),
        );
    } else {
        let at = m * left / parts;
        let (a1, a2) = a.split_at(Axis(0), at);
        let (c1, c2) = c.split_at(Axis(0), at);
        rayon::join(
            || split_mat_mul(a1, b, c1, left),
            || split_mat_mul(a2, b, c2, right),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::linalg::general_mat_mul;

    /// The forward output and every gradient for input `x`.
    fn pass(mlp: &HostMlp, x: HostInput<'_>) -> (Array2<f32>, HostMlp) {
        let mut work = MlpWork::default();
        mlp.forward(x, &mut work);
        let out = work.output().clone();
        let (o, g) = work.output_and_grad();
        g.assign(&o.mapv(|v| v - 0.5));
        let mut grads = mlp.zeros_like();
        mlp.backward(x, &mut work, &mut grads);
        (out, grads)
    }

    #[test]
    fn one_hot_inputs_as_sparse_rows_give_the_dense_pass_values() {
        let (rows, input) = (6, 40);
        let value = |i: usize, j: usize| ((i * 7 + j * 3) % 11) as f32 / 11.0 - 0.5;
        let mlp = HostMlp {
            w: vec![
                Array2::from_shape_fn((input, 5), |(i, j)| value(i, j)),
                Array2::from_shape_fn((3, 5), |(i, j)| value(j + 1, i)), // [out, in]
            ],
            b: vec![Array1::from(vec![0.1; 5]), Array1::from(vec![-0.2; 3])],
            skip: Some(Array2::from_shape_fn((input, 3), |(i, j)| value(j + 2, i))),
        };
        // two non-zero entries per row of 40
        let mut x = Array2::zeros((rows, input));
        for r in 0..rows {
            x[[r, r * 5]] = 1.0;
            x[[r, 39 - r]] = 0.5;
        }
        let sparse = SparseRows::from_dense(x.view()).expect("mostly zeros");
        let (out_sparse, g_sparse) = pass(&mlp, HostInput::Sparse(&sparse));
        let (out_dense, g_dense) = pass(&mlp, HostInput::Dense(x.view()));
        assert!((&out_sparse - &out_dense).iter().all(|d| d.abs() < 1e-6));
        for (a, b) in g_sparse.slices().iter().zip(g_dense.slices()) {
            assert!(a.iter().zip(b).all(|(p, q)| (p - q).abs() < 1e-6));
        }
    }

    #[test]
    fn burn_weights_round_trip_and_the_host_pass_equals_burns() {
        use crate::{BurnDevice, DeviceKind};
        use rand::SeedableRng;
        let device = DeviceKind::Flex.device();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let config = crate::MlpConfig {
            input: 5,
            hidden: vec![4, 6],
            output: 3,
            output_gain: 1.0,
            skip: true,
            zero_inputs: 0,
            skip_identity: None,
        };
        let mut mlp = config.init(&mut rng, &device);
        let host = HostMlp::from_burn(&mlp);
        // the first layer in burn's [in, out], the later ones [out, in]
        let dims: Vec<_> = host.w.iter().map(|w| w.dim()).collect();
        assert_eq!(dims, vec![(5, 4), (6, 4), (3, 6)]);
        for (i, layer) in mlp.layers().iter().enumerate() {
            let burn: Vec<f32> = crate::to_vec(layer.weight.val());
            assert_eq!(host.weight(i).iter().copied().collect::<Vec<_>>(), burn);
        }
        let x = Array2::from_shape_fn((3, 5), |(i, j)| (i * 5 + j) as f32 * 0.1 - 0.7);
        let data = x.iter().copied().collect();
        let burn_out = crate::to_vec(mlp.forward(crate::tensor2(data, 3, 5, &device)));
        let mut work = MlpWork::default();
        host.forward(HostInput::Dense(x.view()), &mut work);
        for (h, b) in work.output().iter().zip(&burn_out) {
            assert!((h - b).abs() < 1e-5, "{h} vs {b}");
        }
        // changed on the host, written back, read again: the same weights
        let mut changed = host.clone();
        for (k, piece) in changed.slices_mut().into_iter().enumerate() {
            for (j, v) in piece.iter_mut().enumerate() {
                *v += (k * 10 + j) as f32 * 0.01;
            }
        }
        mlp.set_from_host(&changed);
        assert_eq!(HostMlp::from_burn(&mlp), changed);
    }

    #[test]
    fn products_split_into_any_number_of_parts_equal_one_product() {
        let value = |i: usize, j: usize| ((i * 13 + j * 7) % 17) as f32 / 17.0 - 0.5;
        // c wider than tall (columns split) and taller than wide (rows split)
        for (m, k, n) in [(48, 64, 1500), (1500, 64, 48)] {
            let a = Array2::from_shape_fn((m, k), |(i, j)| value(i, j));
            let b = Array2::from_shape_fn((k, n), |(i, j)| value(i + 3, j));
            let mut whole = Array2::zeros((m, n));
            general_mat_mul(1.0, &a, &b, 0.0, &mut whole);
            for parts in [1, 2, 3, 5] {
                let mut c = Array2::from_elem((m, n), f32::NAN);
                split_mat_mul(a.view(), b.view(), c.view_mut(), parts);
                // every entry written (no NaN left) and equal to the whole product's
                let diff = &c - &whole;
                assert!(
                    diff.iter().all(|d| d.abs() < 1e-5),
                    "{m}x{k}x{n} in {parts} parts"
                );
            }
        }
    }
}
