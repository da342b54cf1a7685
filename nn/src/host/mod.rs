//! Training on the host without a tensor graph: an MLP's forward and backward pass over
//! preallocated buffers with the dense products on a GEMM kernel (ndarray's matrixmultiply),
//! vectorisable `exp`/`tanh` (`math`), and Adam with global gradient-norm clipping (`adam`),
//! equal to burn's. At minibatch sizes like PPO's 64 a graph of small tensor operations
//! costs far more in per-operation overhead than in arithmetic; these do the arithmetic only.
//!
//! The weights are copies of burn modules' parameters ([`HostMlp::from_burn`]) written back
//! with [`crate::Mlp::set_from_host`]: the burn module stays the one model definition.

mod adam;
pub mod math;

use ndarray::linalg::general_mat_mul;
use ndarray::{Array1, Array2, ArrayView2, Axis};

pub use adam::{HostAdam, clip_global_norm};

/// An MLP's weights on the host: `w[i]` is `[in, out]` (burn's layout), `b[i]` is `[out]`;
/// tanh between layers, none after the last.
#[derive(Debug, Clone, PartialEq)]
pub struct HostMlp {
    /// Weights per layer, `[in, out]`.
    pub w: Vec<Array2<f32>>,
    /// Biases per layer, `[out]`.
    pub b: Vec<Array1<f32>>,
}

/// One MLP pass's buffers, kept between minibatches.
#[derive(Debug, Clone, Default)]
pub struct MlpWork {
    /// Each layer's output (after tanh for hidden layers).
    acts: Vec<Array2<f32>>,
    /// The loss's gradient at each layer's pre-activation output.
    delta: Vec<Array2<f32>>,
    /// Whether the last forward pass's input took the sparse first layer.
    sparse_input: bool,
}

/// `a` as a `rows x cols` array, reallocated only when the shape changes.
fn shaped(a: &mut Array2<f32>, rows: usize, cols: usize) {
    if a.dim() != (rows, cols) {
        *a = Array2::zeros((rows, cols));
    }
}

impl MlpWork {
    /// The output of the last [`HostMlp::forward`], `[batch, output]`.
    pub fn output(&self) -> &Array2<f32> {
        &self.acts[self.acts.len() - 1]
    }

    /// The output (read) and the buffer of its gradient (written), together.
    pub fn output_and_grad(&mut self) -> (&Array2<f32>, &mut Array2<f32>) {
        let last = self.acts.len() - 1;
        (&self.acts[last], &mut self.delta[last])
    }
}

impl HostMlp {
    /// A copy of `mlp`'s weights.
    pub fn from_burn(mlp: &crate::Mlp) -> Self {
        let mut w = Vec::new();
        let mut b = Vec::new();
        for layer in mlp.layers() {
            let weight = layer.weight.val();
            let [rows, cols] = weight.dims();
            let data = crate::to_vec(weight);
            w.push(
                Array2::from_shape_vec((rows, cols), data)
                    .unwrap_or_else(|_| Array2::zeros((rows, cols))),
            );
            let bias = layer
                .bias
                .as_ref()
                .map_or_else(|| vec![0.0; cols], |p| crate::to_vec(p.val()));
            b.push(Array1::from(bias));
        }
        Self { w, b }
    }

    /// Zeros in this MLP's shape (gradients, optimiser moments).
    pub fn zeros_like(&self) -> Self {
        Self {
            w: self.w.iter().map(|w| Array2::zeros(w.raw_dim())).collect(),
            b: self.b.iter().map(|b| Array1::zeros(b.raw_dim())).collect(),
        }
    }

    /// Every parameter as a flat slice, weights and bias of each layer in turn.
    pub fn slices(&self) -> Vec<&[f32]> {
        let mut out = Vec::with_capacity(2 * self.w.len());
        for (w, b) in self.w.iter().zip(&self.b) {
            out.push(w.as_slice().unwrap_or(&[]));
            out.push(b.as_slice().unwrap_or(&[]));
        }
        out
    }

    /// Every parameter as a flat mutable slice, in the order of [`Self::slices`].
    pub fn slices_mut(&mut self) -> Vec<&mut [f32]> {
        let mut out = Vec::with_capacity(2 * self.w.len());
        for (w, b) in self.w.iter_mut().zip(&mut self.b) {
            out.push(w.as_slice_mut().unwrap_or(&mut []));
            out.push(b.as_slice_mut().unwrap_or(&mut []));
        }
        out
    }

    /// Runs `x` (`[batch, input]`) through the layers into `work`; the output is
    /// [`MlpWork::output`].
    pub fn forward(&self, x: ArrayView2<'_, f32>, work: &mut MlpWork) {
        let n = self.w.len();
        let rows = x.nrows();
        work.acts.resize_with(n, Default::default);
        work.delta.resize_with(n, Default::default);
        for i in 0..n {
            let cols = self.w[i].ncols();
            shaped(&mut work.acts[i], rows, cols);
            shaped(&mut work.delta[i], rows, cols);
            let (done, rest) = work.acts.split_at_mut(i);
            let out = &mut rest[0];
            if i == 0 {
                work.sparse_input = mostly_zeros(x);
            }
            if i == 0 && work.sparse_input {
                sparse_mul(x, &self.w[0], out);
            } else {
                let input = if i == 0 { x } else { done[i - 1].view() };
                general_mat_mul(1.0, &input, &self.w[i], 0.0, out);
            }
            let bias = self.b[i].as_slice().unwrap_or(&[]);
            let data = out.as_slice_mut().unwrap_or(&mut []);
            for row in data.chunks_exact_mut(cols.max(1)) {
                if i + 1 < n {
                    for (z, &bj) in row.iter_mut().zip(bias) {
                        *z = math::tanh(*z + bj);
                    }
                } else {
                    for (z, &bj) in row.iter_mut().zip(bias) {
                        *z += bj;
                    }
                }
            }
        }
    }

    /// The gradients of every weight and bias into `grads` (same shapes as `self`), from the
    /// gradient the caller wrote at [`MlpWork::output_and_grad`] after [`Self::forward`] on `x`.
    pub fn backward(&self, x: ArrayView2<'_, f32>, work: &mut MlpWork, grads: &mut HostMlp) {
        for i in (0..self.w.len()).rev() {
            let (lower, upper) = work.delta.split_at_mut(i);
            let delta = &upper[0];
            if i == 0 && work.sparse_input {
                sparse_outer(x, delta, &mut grads.w[0]);
            } else {
                let input = if i == 0 { x } else { work.acts[i - 1].view() };
                general_mat_mul(1.0, &input.t(), delta, 0.0, &mut grads.w[i]);
            }
            grads.b[i].assign(&delta.sum_axis(Axis(0)));
            if i > 0 {
                let below = &mut lower[i - 1];
                general_mat_mul(1.0, delta, &self.w[i].t(), 0.0, below);
                // through the tanh of layer i-1: d tanh = 1 - tanh^2
                below.zip_mut_with(&work.acts[i - 1], |g, &a| *g *= 1.0 - a * a);
            }
        }
    }
}

/// Whether at most an eighth of `x` is non-zero (one-hot inputs): the first layer then
/// skips the zeros instead of multiplying them.
fn mostly_zeros(x: ArrayView2<'_, f32>) -> bool {
    let nonzero = x.iter().filter(|&&v| v != 0.0).count();
    nonzero * 8 <= x.len()
}

/// `out = x w`, visiting only the non-zero entries of `x`.
fn sparse_mul(x: ArrayView2<'_, f32>, w: &Array2<f32>, out: &mut Array2<f32>) {
    out.fill(0.0);
    for (x_row, mut out_row) in x.rows().into_iter().zip(out.rows_mut()) {
        for (j, &v) in x_row.iter().enumerate() {
            if v != 0.0 {
                out_row.scaled_add(v, &w.row(j));
            }
        }
    }
}

/// `g = x^T delta`, visiting only the non-zero entries of `x`.
fn sparse_outer(x: ArrayView2<'_, f32>, delta: &Array2<f32>, g: &mut Array2<f32>) {
    g.fill(0.0);
    for (x_row, d_row) in x.rows().into_iter().zip(delta.rows()) {
        for (j, &v) in x_row.iter().enumerate() {
            if v != 0.0 {
                g.row_mut(j).scaled_add(v, &d_row);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3-layer MLP's forward output and weight gradients, for inputs `x`.
    fn pass(mlp: &HostMlp, x: &Array2<f32>) -> (Array2<f32>, HostMlp) {
        let mut work = MlpWork::default();
        mlp.forward(x.view(), &mut work);
        let out = work.output().clone();
        let (o, g) = work.output_and_grad();
        g.assign(&o.mapv(|v| v - 0.5));
        let mut grads = mlp.zeros_like();
        mlp.backward(x.view(), &mut work, &mut grads);
        (out, grads)
    }

    #[test]
    fn one_hot_inputs_take_the_sparse_path_to_the_same_values() {
        let (rows, input) = (6, 40);
        let value = |i: usize, j: usize| ((i * 7 + j * 3) % 11) as f32 / 11.0 - 0.5;
        let mlp = HostMlp {
            w: vec![
                Array2::from_shape_fn((input, 5), |(i, j)| value(i, j)),
                Array2::from_shape_fn((5, 3), |(i, j)| value(i + 1, j)),
            ],
            b: vec![Array1::from(vec![0.1; 5]), Array1::from(vec![-0.2; 3])],
        };
        // two non-zero entries per row of 40
        let mut x = Array2::zeros((rows, input));
        for r in 0..rows {
            x[[r, r * 5]] = 1.0;
            x[[r, 39 - r]] = 0.5;
        }
        assert!(mostly_zeros(x.view()));
        let (out_sparse, g_sparse) = pass(&mlp, &x);
        // the first layer's product and gradient against the dense GEMMs
        let mut first = Array2::zeros((rows, 5));
        general_mat_mul(1.0, &x, &mlp.w[0], 0.0, &mut first);
        let mut sparse_first = Array2::zeros((rows, 5));
        sparse_mul(x.view(), &mlp.w[0], &mut sparse_first);
        assert!((&first - &sparse_first).iter().all(|d| d.abs() < 1e-6));
        let delta = Array2::from_shape_fn((rows, 5), |(i, j)| value(i, j + 2));
        let mut g_dense = Array2::zeros((input, 5));
        general_mat_mul(1.0, &x.t(), &delta, 0.0, &mut g_dense);
        let mut g_sp = Array2::zeros((input, 5));
        sparse_outer(x.view(), &delta, &mut g_sp);
        assert!((&g_dense - &g_sp).iter().all(|d| d.abs() < 1e-6));
        // and the whole pass equals the dense path's on the same values (the zeros nudged
        // to 1e-30, which changes nothing but the path taken)
        let nudged = x.mapv(|v| if v == 0.0 { 1e-30 } else { v });
        assert!(!mostly_zeros(nudged.view()));
        let (out_dense, g_dense_all) = pass(&mlp, &nudged);
        assert!((&out_sparse - &out_dense).iter().all(|d| d.abs() < 1e-6));
        for (a, b) in g_sparse.slices().iter().zip(g_dense_all.slices()) {
            assert!(a.iter().zip(b).all(|(p, q)| (p - q).abs() < 1e-6));
        }
    }
}
