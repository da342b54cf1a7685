//! The baselines' softmax over every discrete action, computed on the host.
//!
//! The AE reconstructs the action from its embedding and RA's f scores every action against
//! the inferred embedding: both are a cross-entropy over `[batch, n]` logits, 2M values at
//! 4,096 actions. As a graph of burn operations that is many full passes a step, `exp`
//! through libm among them (40% of the AE's pre-training time in a profile; 5 epochs at
//! 4,096 actions took 28.7 s so and 13.2 s this way, docs/src/performance/baselines-embedder.md). Here the logits
//! come from one product on the gemm kernels, the softmax and its gradient
//! `(softmax - onehot) / batch` from one pass with the vectorised `exp`, and the gradients at
//! the few small inputs (`[batch, d]`, `[n, d]`, `[n]`) from two more products. They reach
//! autodiff through [`attach`]: `sum(input * gradient)` per input, whose gradient is the
//! constant, with the forward value replaced by the loss. The result is the same loss and the
//! same gradients as the graph's, to rounding (tested against it below).

use burn::tensor::Tensor;
use jsae_nn::{self as nn, host::math, host::product};
use ndarray::{Array1, Array2, ArrayView2, Axis};

/// Turns `logits` (`[b, n]` row-major) into the gradient of the mean cross-entropy of
/// `targets` at them, `(softmax - onehot) / b`, in place. Returns the mean cross-entropy and
/// `sum(gradient * logits)` (RA's gradient at its log-scale). Compiled for the widest vector
/// instructions the CPU has (pulp's dispatch at run time), as the learner's categorical head.
pub(crate) fn cross_entropy_grad(logits: &mut [f32], n: usize, targets: &[u32]) -> (f32, f32) {
    pulp::Arch::new().dispatch(CrossEntropyRows { logits, n, targets })
}

struct CrossEntropyRows<'a> {
    logits: &'a mut [f32],
    n: usize,
    targets: &'a [u32],
}

impl pulp::WithSimd for CrossEntropyRows<'_> {
    type Output = (f32, f32);

    /// Inlined whole into pulp's function for the instruction set, so its loops are
    /// vectorised for it.
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> (f32, f32) {
        let Self { logits, n, targets } = self;
        let inv_b = 1.0 / targets.len().max(1) as f32;
        let mut exps = vec![0.0f32; n];
        let (mut loss, mut g_dot_logits) = (0.0f64, 0.0f64);
        for (row, &t) in logits.chunks_exact_mut(n).zip(targets) {
            let t = t as usize;
            let shift = math::max(row);
            let sum = math::exp_shifted(&mut exps, row, shift);
            let picked = row[t];
            // sum_a p_a l_a, as sum_a p_a (l_a - shift) + shift
            let expected = math::dot_shifted(&exps, row, shift) / sum + shift;
            loss += f64::from(sum.ln() + shift - picked);
            g_dot_logits += f64::from(expected - picked);
            let scale = inv_b / sum;
            for (g, &e) in row.iter_mut().zip(&exps) {
                *g = e * scale;
            }
            row[t] -= inv_b;
        }
        (
            (loss * f64::from(inv_b)) as f32,
            (g_dot_logits * f64::from(inv_b)) as f32,
        )
    }
}

/// `value` as a `[1]` tensor whose gradient at each `input` is its paired constant.
pub(crate) fn attach(value: f32, terms: Vec<(Tensor<2>, Array2<f32>)>) -> Tensor<1> {
    let mut surrogate: Option<Tensor<1>> = None;
    for (input, grad) in terms {
        let (rows, cols) = grad.dim();
        let grad = nn::tensor2(
            grad.into_raw_vec_and_offset().0,
            rows,
            cols,
            &input.device(),
        );
        let term = (input * grad).sum();
        surrogate = Some(match surrogate {
            None => term,
            Some(s) => s + term,
        });
    }
    let Some(s) = surrogate else {
        unreachable!("attach is given at least one input")
    };
    let device = s.device();
    s.clone() - s.detach() + nn::tensor1(vec![value], &device)
}

/// A `[rows, cols]` tensor's values on the host.
pub(crate) fn host2(t: &Tensor<2>) -> Array2<f32> {
    let [rows, cols] = t.dims();
    Array2::from_shape_vec((rows, cols), nn::to_vec(t.clone()))
        .unwrap_or_else(|_| unreachable!("a tensor's values fill its shape"))
}

/// `a b` into a new array.
pub(crate) fn times(a: ArrayView2<'_, f32>, b: ArrayView2<'_, f32>) -> Array2<f32> {
    let mut c = Array2::zeros((a.nrows(), b.ncols()));
    product(a, b, c.view_mut());
    c
}

/// A `[n]` vector as a `[1, n]` row.
fn row(v: Array1<f32>) -> Array2<f32> {
    v.insert_axis(Axis(0))
}

/// AE: the mean cross-entropy of `targets` under `e w + bias` (`w`: `[d, n]`, a linear
/// layer's weights or a slice of their columns, and its bias).
pub(super) fn linear_cross_entropy(
    e: Tensor<2>,
    w: Tensor<2>,
    bias: Option<Tensor<1>>,
    targets: &[u32],
) -> Tensor<1> {
    let n = w.dims()[1];
    let (e_h, w_h) = (host2(&e), host2(&w));
    let mut logits = times(e_h.view(), w_h.view());
    if let Some(b) = &bias {
        logits += &Array1::from(nn::to_vec(b.clone()));
    }
    let slice = logits
        .as_slice_mut()
        .unwrap_or_else(|| unreachable!("a new array is contiguous"));
    let (loss, _) = cross_entropy_grad(slice, n, targets);
    let g = logits;
    let mut terms = vec![(e, times(g.view(), w_h.t())), (w, times(e_h.t(), g.view()))];
    if let Some(b) = bias {
        terms.push((b.unsqueeze_dim(0), row(g.sum_axis(Axis(0)))));
    }
    attach(loss, terms)
}

/// RA: the mean cross-entropy of `targets` under `-scale * |e - z_a|^2` for every point `z_a`
/// (`z`: `[n, d]`, `scale = exp(log_scale)`). Each row's constant `-scale * |e|^2` is left out
/// of the logits (a softmax does not see it) and put back in the log-scale's gradient.
pub(super) fn distance_cross_entropy(
    e: Tensor<2>,
    z: Tensor<2>,
    log_scale: Tensor<1>,
    targets: &[u32],
) -> Tensor<1> {
    let (e_h, z_h) = (host2(&e), host2(&z));
    let scale = nn::to_vec(log_scale.clone())[0].exp();
    let n = z_h.nrows();
    let z_sq = z_h.map_axis(Axis(1), |r| r.dot(&r));
    let e_sq = e_h.map_axis(Axis(1), |r| r.dot(&r));
    let mut logits = times(e_h.view(), z_h.t()) * (2.0 * scale);
    logits -= &(z_sq * scale);
    let slice = logits
        .as_slice_mut()
        .unwrap_or_else(|| unreachable!("a new array is contiguous"));
    let (loss, g_dot_logits) = cross_entropy_grad(slice, n, targets);
    let g = logits;
    // sum over a row of the gradient is 0 up to rounding; kept so the gradients are exact
    let row_sums = g.sum_axis(Axis(1));
    let col_sums = g.sum_axis(Axis(0));
    let two_s = 2.0 * scale;
    let de = (times(g.view(), z_h.view()) - &e_h * &row_sums.view().insert_axis(Axis(1))) * two_s;
    let dz = (times(g.t(), e_h.view()) - &z_h * &col_sums.view().insert_axis(Axis(1))) * two_s;
    let d_log_scale = g_dot_logits - scale * e_sq.dot(&row_sums);
    attach(
        loss,
        vec![
            (e, de),
            (z, dz),
            (
                log_scale.unsqueeze_dim(0),
                Array2::from_elem((1, 1), d_log_scale),
            ),
        ],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::cross_entropy;
    use burn::module::Param;
    use burn::tensor::{Device, Int, TensorData};
    use jsae_agent::embedding::uniform_linear;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const B: usize = 7;
    const N: usize = 37;
    const D: usize = 3;

    fn device() -> Device {
        Device::flex().autodiff()
    }

    fn param(rows: usize, cols: usize, rng: &mut ChaCha8Rng) -> Param<Tensor<2>> {
        let v = (0..rows * cols)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        Param::from_tensor(nn::tensor2(v, rows, cols, &device()))
    }

    fn targets(rng: &mut ChaCha8Rng) -> (Vec<u32>, Tensor<2, Int>) {
        let t: Vec<u32> = (0..B).map(|_| rng.random_range(0..N as u32)).collect();
        let idx = t.iter().map(|&a| i64::from(a)).collect();
        (
            t,
            Tensor::from_data(TensorData::new(idx, [B, 1]), &device()),
        )
    }

    fn close(a: &[f32], b: &[f32]) {
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-5 + 1e-4 * y.abs(), "{x} against {y}");
        }
    }

    fn grad2(p: &Param<Tensor<2>>, grads: &burn::tensor::Gradients) -> Vec<f32> {
        nn::to_vec(p.val().grad(grads).expect("a gradient"))
    }

    #[test]
    fn the_linear_head_gives_the_graphs_loss_and_gradients() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let table = param(N, D, &mut rng);
        let decoder = uniform_linear(D, N, true, &mut rng, &device());
        let (t, idx) = targets(&mut rng);
        let e = || table.val().slice([0..B, 0..D]).tanh();
        let graph = cross_entropy(decoder.forward(e()), idx);
        let bias = decoder.bias.as_ref().map(|b| b.val());
        let host = linear_cross_entropy(e(), decoder.weight.val(), bias, &t);
        close(&nn::to_vec(host.clone()), &nn::to_vec(graph.clone()));
        let (gg, hg) = (graph.backward(), host.backward());
        close(&grad2(&table, &hg), &grad2(&table, &gg));
        close(&grad2(&decoder.weight, &hg), &grad2(&decoder.weight, &gg));
        let bias = decoder.bias.as_ref().expect("a bias");
        let bias_grad = |g| nn::to_vec(bias.val().grad(g).expect("a gradient"));
        close(&bias_grad(&hg), &bias_grad(&gg));
    }

    #[test]
    fn the_distance_head_gives_the_graphs_loss_and_gradients() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let (inputs, table) = (param(B, D, &mut rng), param(N, D, &mut rng));
        let log_scale = Param::from_tensor(nn::tensor1(vec![1.3], &device()));
        let (t, idx) = targets(&mut rng);
        let ez = || (inputs.val().tanh(), table.val().tanh());
        let (e, z) = ez();
        let dist = e.clone().square().sum_dim(1) + z.clone().square().sum_dim(1).transpose()
            - e.clone().matmul(z.clone().transpose()) * 2.0;
        let logits = dist * log_scale.val().exp().reshape([1, 1]).neg();
        let graph = cross_entropy(logits, idx);
        let (e, z) = ez(); // a graph of its own: burn's tape is consumed by a backward pass
        let host = distance_cross_entropy(e, z, log_scale.val(), &t);
        close(&nn::to_vec(host.clone()), &nn::to_vec(graph.clone()));
        let (gg, hg) = (graph.backward(), host.backward());
        close(&grad2(&inputs, &hg), &grad2(&inputs, &gg));
        close(&grad2(&table, &hg), &grad2(&table, &gg));
        let scale_grad = |g| nn::to_vec(log_scale.val().grad(g).expect("a gradient"));
        close(&scale_grad(&hg), &scale_grad(&gg));
    }

    #[test]
    fn each_row_of_the_gradient_is_softmax_less_the_target() {
        let mut logits = vec![0.0, 0.0, (2.0f32).ln(), 0.0, 0.0, 0.0];
        let (loss, _) = cross_entropy_grad(&mut logits, 3, &[2, 0]);
        // row 1: p = (1/4, 1/4, 1/2), target 2; row 2: p = 1/3 each, target 0
        let expected = [0.125, 0.125, -0.25, -1.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0];
        close(&logits, &expected);
        close(&[loss], &[(2.0f32.ln() + 3.0f32.ln()) / 2.0]);
    }
}
