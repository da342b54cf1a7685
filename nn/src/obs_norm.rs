//! Input normalisation that belongs to a network: running mean and variance kept as
//! parameters of the module (so they travel in every snapshot and checkpoint of it), never
//! trained by gradients (read detached), updated from host data by their owner. The policy
//! uses it on its input (the learner updates it after each update), the embedding model on
//! real-valued states. Normalised values are clipped to +-10.

use crate as nn;
use burn::module::{Module, Param};
use burn::tensor::{Device, Tensor};

/// Running statistics of the policy input.
#[derive(Module, Debug)]
pub struct ObsNorm {
    mean: Param<Tensor<1>>,
    var: Param<Tensor<1>>,
    /// One value: the (fractional) number of rows seen.
    count: Param<Tensor<1>>,
}

impl ObsNorm {
    /// Added to the variance before its square root.
    pub const EPS: f32 = 1e-8;
    /// Normalised values are clipped to `+-CLIP`.
    pub const CLIP: f32 = 10.0;

    /// Identity statistics for inputs of width `dim`.
    pub fn new(dim: usize, device: &Device) -> Self {
        Self {
            mean: Param::from_tensor(Tensor::zeros([dim], device)),
            var: Param::from_tensor(Tensor::ones([dim], device)),
            count: Param::from_tensor(nn::tensor1(vec![1e-4], device)),
        }
    }

    /// `clip((x - mean) / sqrt(var + eps), -10, 10)`, `[batch, dim]`, with no gradient into
    /// the statistics.
    pub fn apply(&self, x: Tensor<2>) -> Tensor<2> {
        let [_, dim] = x.dims();
        let mean = self.mean.val().detach().reshape([1, dim]);
        let std = self
            .var
            .val()
            .detach()
            .add_scalar(Self::EPS)
            .sqrt()
            .reshape([1, dim]);
        ((x - mean) / std).clamp(-Self::CLIP, Self::CLIP)
    }

    /// Current mean and variance.
    pub fn stats(&self) -> (Vec<f32>, Vec<f32>, f64) {
        let count = nn::to_vec(self.count.val()).first().copied().unwrap_or(0.0);
        (
            nn::to_vec(self.mean.val()),
            nn::to_vec(self.var.val()),
            f64::from(count),
        )
    }

    /// Merges the rows of `x` (`[rows, dim]` row-major) into the statistics (the parallel
    /// variance formula, in f64).
    pub fn update(&mut self, x: &[f32], device: &Device) {
        let (mean, var, count) = self.stats();
        let dim = mean.len();
        let rows = x.len() / dim.max(1);
        if rows == 0 {
            return;
        }
        let n = rows as f64;
        let mut b_mean = vec![0.0f64; dim];
        for row in x.chunks_exact(dim) {
            for (m, &v) in b_mean.iter_mut().zip(row) {
                *m += f64::from(v);
            }
        }
        b_mean.iter_mut().for_each(|m| *m /= n);
        let mut b_var = vec![0.0f64; dim];
        for row in x.chunks_exact(dim) {
            for ((s, &v), m) in b_var.iter_mut().zip(row).zip(&b_mean) {
                let d = f64::from(v) - m;
                *s += d * d;
            }
        }
        b_var.iter_mut().for_each(|s| *s /= n);
        let total = count + n;
        let (mut new_mean, mut new_var) = (Vec::with_capacity(dim), Vec::with_capacity(dim));
        for i in 0..dim {
            let delta = b_mean[i] - f64::from(mean[i]);
            new_mean.push((f64::from(mean[i]) + delta * n / total) as f32);
            let m2 = f64::from(var[i]) * count + b_var[i] * n + delta * delta * count * n / total;
            new_var.push((m2 / total) as f32);
        }
        self.mean = Param::from_tensor(nn::tensor1(new_mean, device));
        self.var = Param::from_tensor(nn::tensor1(new_var, device));
        self.count = Param::from_tensor(nn::tensor1(vec![total as f32], device));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batches_merge_to_the_statistics_of_all_rows() {
        let device = burn::tensor::Device::flex();
        let mut norm = ObsNorm::new(2, &device);
        let rows: Vec<[f32; 2]> = (0..100)
            .map(|i| [i as f32, (i * i) as f32 * 0.01])
            .collect();
        let flat: Vec<f32> = rows.iter().flatten().copied().collect();
        norm.update(&flat[..60], &device);
        norm.update(&flat[60..], &device);
        let (mean, var, count) = norm.stats();
        let m0 = 49.5;
        let v0 = (0..100).map(|i| (i as f64 - m0).powi(2)).sum::<f64>() / 100.0;
        assert!((f64::from(mean[0]) - m0).abs() < 1e-3, "{mean:?}");
        assert!((f64::from(var[0]) - v0).abs() / v0 < 1e-3, "{var:?}");
        assert!((count - 100.0).abs() < 1e-2);
        let x = nn::tensor2(vec![m0 as f32, 0.0, 1e6, 0.0], 2, 2, &device);
        let out = nn::to_vec(norm.apply(x));
        assert!(out[0].abs() < 1e-3 && out[2] == 10.0, "{out:?}");
    }
}
